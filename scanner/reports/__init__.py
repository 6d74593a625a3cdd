"""What a reconstruction reports: the figures' definitions and bands, summary.md, the unit rule,
and the pictures (deviation, residuals, meshes rendered headless)."""
