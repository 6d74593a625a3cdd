"""Mesh files read through Open3D without its libraries' messages on the terminal.

Open3D's PLY reader (RPly) writes a bad file's complaint ("RPly: Wrong magic number. Expected
'ply'") straight to the process's standard error, past Open3D's verbosity setting; the caller
checks the mesh it gets and says what is wrong in its own one-line message instead. Standard
error is therefore pointed at the null device, at the file-descriptor level, while the file is
read.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """File descriptor 2 on the null device for the duration (what C code writes there is
    dropped; Python's own sys.stderr is flushed before and keeps working after)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def read_triangle_mesh(path: Path):
    """open3d.io.read_triangle_mesh(path), quietly: an unreadable file gives an empty mesh,
    which the caller refuses in its own words."""
    import open3d as o3d

    with native_stderr_silenced():
        return o3d.io.read_triangle_mesh(str(path))
