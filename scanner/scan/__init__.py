"""The work of `scanner scan`: configuration, the cell it runs on, viewpoints and their order,
the decision maker, hangings and next-best views, per-view work while the robot moves, and the
scan directory (captures, manifest)."""
