"""Stereo from two poses of one camera: the arm's motion is the baseline.

pairing        which views make pairs (each view and its nearest usable neighbours)
scaling        downscaled views: image, mask and the camera that sees the smaller image
rectification  a view pair as a StereoCamera (quarter turns for vertical or reversed pairs) and
               its rectification at the source's resolution
epipolar       the pair's epipolar error from SIFT matches, and the relative pose refined
cloud          the pair's cloud in the reference camera frame, through the stereo package
"""
