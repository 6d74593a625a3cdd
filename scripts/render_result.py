"""Render result meshes headless (Drake VTK) to a PNG, e.g. for the README.

    python scripts/render_result.py SCAN_DIR/results/mesh_poisson.ply SCAN_DIR/truth_mesh.ply \
        --out docs/result.png
Each mesh is rendered from the same two viewpoints (from below and from the side); images are
tiled one row per mesh. Deviation pictures come with every reconstruction (deviation_*.png)
and from `scanner inspect`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from scanner.reports.mesh_render import render_mesh


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("meshes", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--size", type=int, default=360)
    args = parser.parse_args()
    rows = []
    for path in args.meshes:
        mesh = o3d.io.read_triangle_mesh(str(path))
        images = render_mesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), args.size)
        rows.append(np.hstack(images))
    cv2.imwrite(str(args.out), cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))
    print(args.out)


if __name__ == "__main__":
    main()
