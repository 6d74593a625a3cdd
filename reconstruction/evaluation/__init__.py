"""How good a model is: accuracy against a true or reference surface, signed deviation, coverage
without truth, and a reference brought onto a model."""
