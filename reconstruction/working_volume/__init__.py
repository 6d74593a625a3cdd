"""Where the object is when no cell model says so: its working volume (from masks or the
cameras' common view) and the table it stands on (found in the data, removed)."""
