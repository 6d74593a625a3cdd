"""The stereo camera tool on the RX60 flange: geometry in the flange frame F and the nominal X_FC.

Body size from the Point Grey Bumblebee2 datasheet (157 x 36 x 47.4 mm, W x H x D), mounted on a
25 mm bracket with its lenses looking along the flange's +z. The left optical frame C sits half a
baseline to the -x side of the flange axis, 80 mm in front of the flange face, axes parallel to F
(OpenCV convention: +z forward, +x right, +y down). The right camera R is at +baseline along x_C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BODY_SIZE_M = (0.157, 0.036, 0.0474)
BRACKET_SIZE_M = (0.06, 0.06, 0.025)
# The optical centres sit 7.6 mm in front of the body so that a few mm of hand-eye error
# never puts a simulated lens inside the rendered housing.
LENS_TO_FLANGE_M = 0.080
# The collision box encloses the visual model by at least this much (at least 10 mm, so that
# cables and mounting screws the visual model leaves out stay inside it).
COLLISION_MARGIN_M = 0.012


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the flange frame: centre p_FB (m) and full size (m)."""

    p_FB: tuple[float, float, float]
    size: tuple[float, float, float]


def _box_from_extent(lo: np.ndarray, hi: np.ndarray) -> Box:
    return Box(tuple(((lo + hi) / 2).tolist()), tuple((hi - lo).tolist()))


def tool_visual_boxes() -> list[Box]:
    bracket = Box((0.0, 0.0, BRACKET_SIZE_M[2] / 2), BRACKET_SIZE_M)
    body_z = BRACKET_SIZE_M[2] + BODY_SIZE_M[2] / 2
    body = Box((0.0, 0.0, body_z), BODY_SIZE_M)
    return [bracket, body]


def tool_collision_box() -> Box:
    """One box enclosing bracket, body and lenses with COLLISION_MARGIN_M on every side."""
    boxes = tool_visual_boxes()
    lo = np.min([np.subtract(b.p_FB, np.divide(b.size, 2)) for b in boxes], axis=0)
    hi = np.max([np.add(b.p_FB, np.divide(b.size, 2)) for b in boxes], axis=0)
    hi[2] = max(hi[2], LENS_TO_FLANGE_M)
    return _box_from_extent(lo - COLLISION_MARGIN_M, hi + COLLISION_MARGIN_M)


def rig_X_FC(X_CR: np.ndarray) -> np.ndarray:
    """Nominal pose of the first camera C of a two-camera rig whose second camera sits at X_CR
    in C: the rig centred on the flange axis (for a stereo pair, nominal_X_FC(baseline))."""
    X_FC = nominal_X_FC(0.0)
    X_FC[:2, 3] -= np.asarray(X_CR, float)[:2, 3] / 2
    return X_FC


def nominal_X_FC(baseline_m: float = 0.12) -> np.ndarray:
    """Nominal pose of the left optical frame C in the flange frame F (4x4)."""
    X_FC = np.eye(4)
    X_FC[:3, 3] = (-baseline_m / 2, 0.0, LENS_TO_FLANGE_M)
    return X_FC
