"""Depth (RGB-D) cameras: the device model, and its depth images turned into coloured clouds."""
