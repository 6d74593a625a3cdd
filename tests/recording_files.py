"""Recordings for the import-recording tests: a DTU MVS subset in the IDR form (downscaled by 4,
P scaled to match), synthetic COLMAP projects and plain-form recordings with known poses, and
the check of a refused import (exit 2, one line, nothing written)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import yaml

from reconstruction.common.transforms import invert, make_pose
from reconstruction.recordings import colmap_model
from reconstruction.recordings.colmap import colmap_camera_of, image_of
from reconstruction.stereo.camera_model import PinholeCamera
from tests.conftest import shared_data
from tests.in_process import scanner

DTU = "real/dtu_mvs_scan24"
DTU_VIEWS = 4
DOWNSCALE = 4
# cv2.INTER_AREA by 4: new pixel u' covers old pixels 4u' .. 4u'+3, centre 4u' + 1.5.
S_DOWN = np.array(
    [[1 / DOWNSCALE, 0, -1.5 / DOWNSCALE], [0, 1 / DOWNSCALE, -1.5 / DOWNSCALE], [0, 0, 1]]
)
# DTU scan 24, view 0 (its README: cv2.decomposeProjectionMatrix of P_0).
DTU_FX_PX, DTU_FY_PX, DTU_CX_PX, DTU_CY_PX = 2892.33, 2883.18, 823.21, 619.07
DTU_P_WC0_M = (0.1908, -0.0012, 0.0243)
# Pose comparisons: numbers passed through text files and quaternions, far below a micrometre.
POSE_ATOL_M = 1e-9
ROT_ATOL = 1e-9


# -- helpers ----------------------------------------------------------------------------------
def look_at(p_WC, p_WT=(0.0, 0.0, 0.0)) -> np.ndarray:
    """X_WC of a camera at p_WC whose optical axis (+z) points at p_WT, +y towards -z_W."""
    p_WC = np.asarray(p_WC, float)
    z = np.asarray(p_WT, float) - p_WC
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, -1.0], z)
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), p_WC)


def ring_poses(n: int, radius: float) -> list[np.ndarray]:
    angles = np.linspace(0, np.pi / 2, n)
    return [look_at((radius * np.cos(a), radius * np.sin(a), 0.5 * radius)) for a in angles]


def write_noise_images(folder: Path, names: list[str], width: int, height: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    paths = []
    for name in names:
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), rng.integers(0, 256, (height, width, 3), dtype=np.uint8))
        paths.append(path)
    return paths


def assert_poses_close(X_a: np.ndarray, X_b: np.ndarray) -> None:
    np.testing.assert_allclose(X_a[:3, :3], X_b[:3, :3], atol=ROT_ATOL)
    np.testing.assert_allclose(X_a[:3, 3], X_b[:3, 3], atol=POSE_ATOL_M)


def refused(capfd, source: Path, out: Path, *options) -> str:
    """The one-line error of an import that must fail with exit 2 and write nothing."""
    r = scanner(capfd, "import-recording", source, "--out", out, *options)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    return r.stderr


# -- IDR (DTU subset) -------------------------------------------------------------------------
def dtu_small_folder(parent: Path, views: int = DTU_VIEWS) -> Path:
    """PARENT/dtu_small: an IDR folder of the first `views` DTU views, images and masks
    downscaled by 4 and P scaled to match (pixel centres kept where OpenCV puts them); skips
    without the data."""
    src = shared_data(DTU)
    folder = parent / "dtu_small"
    (folder / "images").mkdir(parents=True)
    (folder / "mask").mkdir()
    cams = np.load(src / "cameras_sphere.npz")
    out = {}
    for i in range(views):
        image = cv2.imread(str(src / "images" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(src / "mask" / f"{i:03d}.png"), cv2.IMREAD_UNCHANGED)
        size = (image.shape[1] // DOWNSCALE, image.shape[0] // DOWNSCALE)
        cv2.imwrite(
            str(folder / "images" / f"{i:06d}.png"),
            cv2.resize(image, size, interpolation=cv2.INTER_AREA),
        )
        cv2.imwrite(
            str(folder / "mask" / f"{i:03d}.png"),
            cv2.resize(mask, size, interpolation=cv2.INTER_AREA),
        )
        P = cams[f"world_mat_{i}"].astype(float)
        P[:3] = S_DOWN @ P[:3]
        out[f"world_mat_{i}"] = P
        out[f"scale_mat_{i}"] = cams[f"scale_mat_{i}"]
    np.savez(folder / "cameras_sphere.npz", **out)
    return folder


def copy_of(folder: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(folder, tmp_path / folder.name))


# -- COLMAP -----------------------------------------------------------------------------------
COLMAP_UNIT_M = 0.25  # metres per model unit of the synthetic models
COLMAP_NAMES = ["a/frame_000.png", "a/frame_001.png", "a/frame_002.png", "a/frame_003.png"]
COLMAP_CAMERA = PinholeCamera(
    np.array([[70.0, 0, 31.5], [0, 72.0, 23.25], [0, 0, 1]]),
    np.array([-0.1, 0.02, 0.001, -0.002, 0.0]),
    64,
    48,
)


def colmap_project(
    tmp_path: Path, binary: bool, camera=None, names=COLMAP_NAMES
) -> tuple[Path, list]:
    """A COLMAP project with known X_WC (metres) of four views: images/ and sparse/0/."""
    X_WC_m = ring_poses(len(names), 1.0)
    images = {}
    for k, (name, X_WC) in enumerate(zip(names, X_WC_m, strict=True)):
        X_WC_units = X_WC.copy()
        X_WC_units[:3, 3] /= COLMAP_UNIT_M
        # Ids need not follow the names' order: the reader orders views by name.
        images[10 - k] = image_of(invert(X_WC_units), 10 - k, 1, name)
    cam = camera if camera is not None else colmap_camera_of(COLMAP_CAMERA, 1)
    project = tmp_path / "colmap_project"
    colmap_model.write_model(
        project / "sparse" / "0", colmap_model.ColmapModel({1: cam}, images), binary
    )
    write_noise_images(project / "images", names, cam.width, cam.height)
    return project, X_WC_m


# -- plain form -------------------------------------------------------------------------------
def plain_recording(tmp_path: Path, n: int = 3, depth: bool = True) -> tuple[Path, dict, list]:
    """recording.yaml in millimetres with flange poses X_WF and a top-level X_FC; masks and
    16-bit depth images."""
    folder = tmp_path / "plain_rec"
    write_noise_images(folder / "img", [f"{i}.png" for i in range(n)], 32, 24)
    (folder / "masks").mkdir()
    X_FC_m = make_pose(np.eye(3), (0.01, -0.02, 0.1))
    X_WF_m = [X @ invert(X_FC_m) for X in ring_poses(n, 0.5)]
    views = []
    for i, X_WF in enumerate(X_WF_m):
        mask = np.zeros((24, 32), np.uint8)
        mask[5:15, 8:20] = 1  # 0/1 masks occur; imported as 0/255
        cv2.imwrite(str(folder / "masks" / f"{i}.png"), mask)
        X_mm = X_WF.copy()
        X_mm[:3, 3] *= 1000
        view = {"image": f"img/{i}.png", "X_WF": X_mm.tolist(), "mask": f"masks/{i}.png"}
        if depth:
            cv2.imwrite(str(folder / f"depth{i}.png"), np.full((24, 32), 500 + i, np.uint16))
            view["depth"] = f"depth{i}.png"
        views.append(view)
    X_FC_mm = X_FC_m.copy()
    X_FC_mm[:3, 3] *= 1000
    doc = {
        "unit_m": 0.001,
        "K": [[30.0, 0, 15.5], [0, 30.0, 11.5], [0, 0, 1]],
        "X_FC": X_FC_mm.tolist(),
        "depth_unit_m": 0.0001,
        "views": views,
    }
    (folder / "recording.yaml").write_text(yaml.safe_dump(doc))
    return folder, doc, [X @ X_FC_m for X in X_WF_m]
