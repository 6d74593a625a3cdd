"""The work of `scanner reconstruct` and `scanner merge`: saved captures -> views -> the
reconstruction pipeline -> the evaluation against the simulator's truth -> a results folder;
batches on Ray; progress on the terminal."""
