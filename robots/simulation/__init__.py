"""The simulated cell that stands in for hardware: the true world and its error model, the
simulated robot and cameras, the operator who re-hangs the object, the cell video, the live view."""
