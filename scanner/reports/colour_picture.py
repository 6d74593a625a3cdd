"""The model in its own colours (taken from the images it was built from), seen from where the
cameras stood: what a recording's model looks like, with no reference to compare it with."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from scanner.reports.mesh_render import render_mesh

PICTURE_NAME = "model_colours.png"
SIZE_PX = 480


def picture_directions(centre_W: np.ndarray, eyes_W: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Two directions from the model's centre: towards the middle of the cameras (the view the
    recording was made for) and towards the camera farthest from that (its widest other
    side)."""
    towards = [np.asarray(e, float) - centre_W for e in eyes_W]
    towards = [d / np.linalg.norm(d) for d in towards if np.linalg.norm(d) > 0]
    middle = np.mean(towards, axis=0)
    if np.linalg.norm(middle) < 1e-9:  # cameras all around: any one of them
        middle = towards[0]
    middle /= np.linalg.norm(middle)
    farthest = min(towards, key=lambda d: float(d @ middle))
    return [middle, farthest]


def write_colour_picture(
    vertices: np.ndarray,
    triangles: np.ndarray,
    vertex_rgb: np.ndarray,
    X_WC: Sequence[np.ndarray],
    path: Path,
) -> Path:
    """Two views of the mesh in its vertex colours ((V, 3), 0-255), side by side, from the
    directions of `picture_directions` towards the cameras (X_WC), with the cameras' mean up
    (their -y) up."""
    v = np.asarray(vertices, float)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    images = render_mesh(
        v,
        triangles,
        size_px=SIZE_PX,
        directions=picture_directions(centre, [X[:3, 3] for X in X_WC]),
        vertex_rgb=vertex_rgb,
        up_W=-np.mean([X[:3, 1] for X in X_WC], axis=0),
    )
    picture = np.hstack(images)
    for k, label in enumerate(("from the cameras' middle", "from the farthest camera")):
        cv2.putText(
            picture, label, (10 + k * SIZE_PX, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1
        )
    if not cv2.imwrite(str(path), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: could not be written")
    return Path(path)
