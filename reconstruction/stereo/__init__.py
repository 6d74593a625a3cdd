"""Stereo: rectification, SGBM matching and its filters, reprojection to clouds, accuracy.

rectification  undistortion + rectification maps of a calibrated pair (once per model)
params         matcher settings and the disparity window derived from a depth window
matching       SGBM disparity of a rectified pair, with the rejection filters applied
filters        masks that reject unreliable disparities (texture, jumps, left-right)
cloud          disparities -> points in the left optical frame C, depth maps for fusion
metrics        accuracy of a cloud against a true depth image (simulator ground truth)
"""
