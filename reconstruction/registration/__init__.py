"""Views into one frame: the per-view input record, per-view filtering, pairwise ICP, the pose
graph, and all views of a hanging registered among themselves."""
