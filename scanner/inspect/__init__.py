"""`scanner inspect`: a measured model against its CAD reference, with a pass/fail verdict."""
