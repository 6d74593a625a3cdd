"""Surfaces from the posed views: the fused cloud and its normals, Poisson (in a solver
process), TSDF, RBF and ball pivoting meshes, mesh topology repairs, and export for CAD users."""
