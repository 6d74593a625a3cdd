"""Basics every layer shares: user-facing errors, config checks, rigid transforms, YAML files,
stage timing, robust losses. Pure Python and numpy; imports nothing of the product."""
