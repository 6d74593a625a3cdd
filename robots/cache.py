"""Where generated files are kept between runs (textured objects, roadmaps, converted meshes,
rendered boards and markers): $SCANNER_CACHE, else ~/.cache/scanner. Each kind has its own
folder below it, its files named by a fingerprint of what they were made from."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    return Path(os.environ.get("SCANNER_CACHE", Path.home() / ".cache" / "scanner"))
