"""The smallest simulated scan the end-to-end tests use: 5 views at 320x240, a small roadmap and
coarse surfaces (the tests check behaviour, not accuracy); and the half-resolution camera of the
tests that check accuracy on fewer pixels."""

from dataclasses import replace

from reconstruction.stereo.camera_model import StereoDesign

# Measured on the tiny scan: 20 -> 11 s a reconstruction (Poisson 5.5 -> 1.6 s, TSDF 2.5 -> 1.2 s,
# evaluation 3.0 -> 0.4 s); its 320x240 views resolve no finer than these 2 mm anyway.
TINY_PROCESSING = {
    "reconstruction": {
        "surfaces": {
            # Both surfaces (the default builds Poisson alone): the tests check each.
            "methods": ["poisson", "tsdf"],
            "poisson_depth": 6,
            "tsdf_voxel_size_m": 0.002,
            "fused_voxel_size_m": 0.002,
        }
    },
    "metric_samples": 20_000,
}

# Five views leave the scan's own hand-eye correction ill-conditioned: it does not converge, and
# the scan would rightly exit with its self-check code. The end-to-end tests check behaviour,
# so the tiny scan keeps the nominal mount; the hand-eye tests scan with more views.
TINY_SCAN = {
    "hangings": 1,
    "camera": {"width_px": 320, "height_px": 240, "focal_px": 330.0},
    "views": {"count": 5, "candidates": 200, "roll_candidates": 4},
    "planner": {"roadmap_milestones": 120, "prm_build_time_s": 20.0},
    "processing": {
        **TINY_PROCESSING,
        "reconstruction": {**TINY_PROCESSING["reconstruction"], "handeye": {"enabled": False}},
    },
}


# The default camera at half its resolution (640x480, the same field of view).
HALF_RESOLUTION = replace(
    StereoDesign(),
    width_px=StereoDesign().width_px // 2,
    height_px=StereoDesign().height_px // 2,
    focal_px=StereoDesign().focal_px / 2,
)
