"""What exists in the cell, as Drake models: the camera tool, the work cell (around any arm of
robots/arms), the objects to scan, the calibration board, forward kinematics, and the points on
robot and cell."""
