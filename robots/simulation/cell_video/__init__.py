"""The video of the static stereo camera watching the cell while the arm moves, with intruders:
what the cell monitor receives, simulated."""
