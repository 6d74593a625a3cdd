"""The smallest simulated scan the end-to-end tests use: 5 views at 320x240 and a small
roadmap (the tests check behaviour, not accuracy)."""

TINY_SCAN = {
    "camera": {"width_px": 320, "height_px": 240, "focal_px": 330.0},
    "views": {"count": 5, "candidates": 200, "roll_candidates": 4},
    "planner": {"roadmap_milestones": 120, "prm_build_time_s": 20.0},
}
