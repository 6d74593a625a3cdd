"""`scanner reconstruct` and `scanner merge`: saved captures -> views -> the reconstruction
pipeline -> a results folder; batches on Ray; progress on the terminal."""
