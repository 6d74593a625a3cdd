"""A calibration board in the work cell: a printed pattern on a plate, on a stand, at true size.

The board is written as a textured OBJ in its own frame B (reconstruction.boards: the pattern in
z = 0, the camera looks along +z_B; the plate extends behind it to +z_B), so that Drake renders
the pattern with its true geometry: a board point p_BP appears exactly where the camera model
projects X_WB @ p_BP. The texture is the BoardImage of the pattern (quiet zone included), mapped
onto the front face by UVs computed from the board's metric layout.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from pydrake.geometry import Box, Mesh
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import SpatialInertia

from reconstruction.calibration.boards import BoardImage, BoardSpec, board_image
from reconstruction.common.checks import check_fields, positive
from reconstruction.common.errors import ScannerError
from robots.models.workcell import textured_instance

BOARD_BODY = "calibration_board"
# Texture resolution: ~5 texels per mm for 20 mm squares, finer than the camera's 2.6-3.8 px/mm
# at 0.35-0.5 m, so the texture grid itself never shows.
TEXELS_PER_SPACING = 96
PLATE_THICKNESS_M = 0.006
# Pre-filter of the printed pattern (see write_board_obj): about one image pixel at 0.4 m.
BLUR_SIGMA_M = 0.0004


@dataclass(frozen=True)
class BoardPlacement:
    """Where the board stands: centre of the pattern area (m, world frame) and its tilt.

    The board faces the direction given by azimuth (about +z_W, 0 = facing +x_W) and elevation
    (0 = vertical board, pi/2 = lying flat facing up); the board's rows run horizontally.
    The stand is a post from the table (z = 0) to the plate's lower edge.
    """

    center_m: tuple[float, float, float] = (0.50, 0.0, 0.12)
    facing_azimuth_rad: float = math.pi
    facing_elevation_rad: float = math.radians(55.0)
    post_size_m: float = positive(0.03)

    def __post_init__(self) -> None:
        if len(self.center_m) != 3 or not all(math.isfinite(v) for v in self.center_m):
            raise ScannerError(
                f"placement.center_m: expected three finite numbers, got {self.center_m}"
            )
        if not -math.pi / 2 <= self.facing_elevation_rad <= math.pi / 2:
            raise ScannerError(
                "placement.facing_elevation_rad: expected an angle within [-pi/2, pi/2], got "
                f"{self.facing_elevation_rad}"
            )
        check_fields("placement", self)

    def X_WB(self, board: BoardSpec) -> np.ndarray:
        """Pose of the board frame B: -z_B (the side the camera sees) faces the given direction,
        the pattern's centre at center_m."""
        az, el = self.facing_azimuth_rad, self.facing_elevation_rad
        n = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        z = -n
        # x_B horizontal, y_B "down the board" (OpenCV rows), right-handed with z_B.
        x = np.cross([0.0, 0.0, 1.0], z)
        if np.linalg.norm(x) < 1e-9:
            x = np.array([0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.column_stack([x, y, z])
        w, h = board.size_m
        X = np.eye(4)
        X[:3, :3] = R
        X[:3, 3] = np.asarray(self.center_m) - R @ np.array([w / 2, h / 2, 0.0])
        return X


def board_fingerprint(board: BoardSpec) -> str:
    return hashlib.sha256(
        f"{board}:{TEXELS_PER_SPACING}:{PLATE_THICKNESS_M}:{BLUR_SIGMA_M}:v1".encode()
    ).hexdigest()[:16]


def write_board_obj(board: BoardSpec, directory: Path) -> Path:
    """board.obj + board.mtl + pattern.png: a plate whose front face (z = 0) carries the pattern."""
    directory = Path(directory)
    obj_path = directory / "board.obj"
    if obj_path.is_file():
        return obj_path
    directory.mkdir(parents=True, exist_ok=True)
    pattern = board_image(board, TEXELS_PER_SPACING)
    # Renderers point-sample textures: a crisp edge finer than a pixel lands on the pixel grid
    # (corners off by up to 0.5 px where edges align with pixel rows). A print seen through a
    # real lens is blurred anyway; pre-filtering the texture by about one image pixel keeps
    # edge positions sub-pixel exact (a symmetric blur does not move an edge or a corner).
    sigma_px = BLUR_SIGMA_M * pattern.px_per_m
    blurred = cv2.GaussianBlur(pattern.image, (0, 0), sigma_px)
    pattern = BoardImage(blurred, pattern.px_per_m, pattern.origin_px)
    # Pad to power-of-two sides (white): a renderer may resample other sizes, which moves edges.
    h_px, w_px = pattern.image.shape
    side_w, side_h = 1 << (w_px - 1).bit_length(), 1 << (h_px - 1).bit_length()
    texture = np.full((side_h, side_w), 255, np.uint8)
    texture[side_h - h_px :, :w_px] = pattern.image
    cv2.imwrite(str(directory / "pattern.png"), texture)
    su, sv = w_px / side_w, h_px / side_h
    (directory / "board.mtl").write_text(
        "newmtl pattern\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd pattern.png\n"
    )
    w, h = pattern.size_m
    ox, oy = pattern.origin_m
    x0, x1, y0, y1, z1 = -ox, w - ox, -oy, h - oy, PLATE_THICKNESS_M
    corners = {
        (i, j, k): (x0 if i == 0 else x1, y0 if j == 0 else y1, 0.0 if k == 0 else z1)
        for i in (0, 1)
        for j in (0, 1)
        for k in (0, 1)
    }
    keys = list(corners)
    lines = ["mtllib board.mtl", "usemtl pattern"]
    lines += ["v {:.7f} {:.7f} {:.7f}".format(*corners[key]) for key in keys]
    index = {key: n + 1 for n, key in enumerate(keys)}
    # OBJ texture v runs up from the image's bottom row; board y runs down the image.
    # The pattern fills the texture's bottom-left su x sv part.
    uv = {
        key: (su * (corners[key][0] + ox) / w, sv * (1.0 - (corners[key][1] + oy) / h))
        for key in keys
    }
    uv_white = (su * 0.5 * ox / w, sv * (1.0 - 0.5 * oy / h))  # in the quiet zone: plain white
    vts = [uv[key] for key in keys] + [uv_white]
    lines += [f"vt {u:.7f} {v:.7f}" for u, v in vts]
    white = len(vts)
    faces = [
        # (corner keys counter-clockwise seen from outside, outward normal, textured?)
        ([(0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)], (0, 0, -1), True),
        ([(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], (0, 0, 1), False),
        ([(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], (0, -1, 0), False),
        ([(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)], (0, 1, 0), False),
        ([(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)], (-1, 0, 0), False),
        ([(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)], (1, 0, 0), False),
    ]
    for _, normal, _ in faces:
        lines.append("vn {} {} {}".format(*normal))
    for n, (quad, _, textured) in enumerate(faces):
        refs = [f"{index[k]}/{index[k] if textured else white}/{n + 1}" for k in quad]
        lines.append(f"f {refs[0]} {refs[1]} {refs[2]}")
        lines.append(f"f {refs[0]} {refs[2]} {refs[3]}")
    tmp = obj_path.with_suffix(".obj.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.rename(obj_path)
    return obj_path


class BoardFixture:
    """Adds the board (visual: textured plate; collision: plate and stand post) to a plant."""

    def __init__(self, board: BoardSpec, placement: BoardPlacement, obj_path: Path) -> None:
        self.board = board
        self.placement = placement
        self.obj_path = Path(obj_path)

    def __call__(self, plant: MultibodyPlant, robot_instance) -> None:
        instance = plant.AddModelInstance(BOARD_BODY)
        body = plant.AddRigidBody(
            BOARD_BODY, instance, SpatialInertia.SolidBoxWithMass(1.0, 0.2, 0.2, 0.01)
        )
        X_WB = self.placement.X_WB(self.board)
        plant.WeldFrames(plant.world_frame(), body.body_frame(), RigidTransform(X_WB))
        plant.RegisterVisualGeometry(
            body, textured_instance(Mesh(str(self.obj_path)), "board_visual", int(body.index()))
        )
        w, h = self.board.size_m
        margin = self.board.spacing_m
        plate = Box(w + 2 * margin, h + 2 * margin, PLATE_THICKNESS_M)
        X_B_plate = RigidTransform(np.array([w / 2, h / 2, PLATE_THICKNESS_M / 2]))
        friction = CoulombFriction(0.5, 0.5)
        plant.RegisterCollisionGeometry(body, X_B_plate, plate, "board_plate", friction)
        # The stand: a vertical post from the table to the plate's centre (behind the plate).
        p_WS = X_WB @ np.array(
            [w / 2, h / 2, PLATE_THICKNESS_M + self.placement.post_size_m / 2, 1]
        )
        height = max(p_WS[2], 0.01)
        X_W_post = RigidTransform(np.array([p_WS[0], p_WS[1], height / 2]))
        post = Box(self.placement.post_size_m, self.placement.post_size_m, height)
        X_B_post = RigidTransform(np.linalg.inv(X_WB)) @ X_W_post
        grey = np.array([0.3, 0.3, 0.32, 1.0])
        plant.RegisterVisualGeometry(body, X_B_post, post, "board_post", grey)
        plant.RegisterCollisionGeometry(body, X_B_post, post, "board_post", friction)
