"""The smallest simulated scan the end-to-end tests use: 5 views at 320x240, a small roadmap and
coarse surfaces (the tests check behaviour, not accuracy)."""

# Measured on the tiny scan: 20 -> 11 s a reconstruction (Poisson 5.5 -> 1.6 s, TSDF 2.5 -> 1.2 s,
# evaluation 3.0 -> 0.4 s); its 320x240 views resolve no finer than these 2 mm anyway.
TINY_PROCESSING = {
    "reconstruction": {
        "surfaces": {
            "poisson_depth": 6,
            "tsdf_voxel_size_m": 0.002,
            "fused_voxel_size_m": 0.002,
        }
    },
    "metric_samples": 20_000,
}

TINY_SCAN = {
    "hangings": 1,
    "camera": {"width_px": 320, "height_px": 240, "focal_px": 330.0},
    "views": {"count": 5, "candidates": 200, "roll_candidates": 4},
    "planner": {"roadmap_milestones": 120, "prm_build_time_s": 20.0},
    "processing": TINY_PROCESSING,
}
