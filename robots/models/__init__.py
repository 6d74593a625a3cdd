"""What exists in the cell, as Drake models: the RX60, the camera tool, the work cell, the objects
to scan, the calibration board, forward kinematics, and the points on robot and cell."""
