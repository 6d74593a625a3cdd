"""What a reconstruction reports: figures against truth, their definitions and bands, summary.md,
and the pictures (deviation, residuals, meshes rendered headless)."""
