"""`scanner import-recording`: recordings of other systems (IDR/NeuS, COLMAP, the plain form)
become scan directories; every bad input is refused in one line with nothing written.

The IDR tests use four DTU MVS scan 24 views downscaled by 4 (P scaled to match); COLMAP and
the plain form are synthetic, with known poses."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose
from reconstruction.recordings import colmap_model
from reconstruction.recordings.colmap import (
    KnownDistance,
    colmap_camera_of,
    image_of,
    pinhole_of,
)
from reconstruction.recordings.formats import read_recording
from reconstruction.stereo.camera_model import PinholeCamera
from scanner.scan_dir.manifest import open_scan
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
@pytest.fixture(scope="module")
def dtu_small(tmp_path_factory) -> Path:
    """An IDR folder of the first DTU views, images and masks downscaled by 4 and P scaled to
    match (pixel centres kept where OpenCV puts them)."""
    src = shared_data(DTU)
    folder = tmp_path_factory.mktemp("idr") / "dtu_small"
    (folder / "images").mkdir(parents=True)
    (folder / "mask").mkdir()
    cams = np.load(src / "cameras_sphere.npz")
    out = {}
    for i in range(DTU_VIEWS):
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


def test_idr_dtu_views_in_metres_with_dtu_intrinsics(dtu_small):
    rec = read_recording(dtu_small)
    assert (rec.format, rec.metres_per_unit, rec.camera_poses_given) == ("idr", 0.001, True)
    assert len(rec.views) == DTU_VIEWS and rec.has_masks
    v0 = rec.views[0]
    # DTU's README gives camera 0's centre in millimetres: here in metres, to 0.1 mm.
    np.testing.assert_allclose(v0.X_WC[:3, 3], DTU_P_WC0_M, atol=1e-4)
    K = v0.camera.K
    np.testing.assert_allclose(
        [K[0, 0], K[1, 1]], [DTU_FX_PX / DOWNSCALE, DTU_FY_PX / DOWNSCALE], atol=0.01
    )
    np.testing.assert_allclose(
        [K[0, 2], K[1, 2]],
        [(DTU_CX_PX - 1.5) / DOWNSCALE, (DTU_CY_PX - 1.5) / DOWNSCALE],
        atol=0.01,
    )
    assert K[0, 1] == 0 and (v0.camera.width, v0.camera.height) == (400, 300)
    # The scene centre (scale_mat's) projects to the same pixel through P and through K, X_WC.
    cams = np.load(dtu_small / "cameras_sphere.npz")
    p_W_mm = cams["scale_mat_0"][:3, 3]
    for v in rec.views:
        P = cams[f"world_mat_{v.index}"][:3]
        x = P @ np.append(p_W_mm, 1)
        p_C = invert(v.X_WC)[:3, :3] @ (p_W_mm * 1e-3) + invert(v.X_WC)[:3, 3]
        assert p_C[2] > 0.5  # DTU's cameras stand 0.64-0.69 m from the scene centre
        ours = (v.camera.K @ p_C)[:2] / p_C[2]
        assert np.linalg.norm(ours - x[:2] / x[2]) < 1e-3  # px


def test_idr_import_writes_a_mono_scan_directory(dtu_small, tmp_path, capfd):
    out = tmp_path / "scan"
    r = scanner(capfd, "import-recording", dtu_small, "--out", out)
    assert r.returncode == 0, r.stderr
    manifest = yaml.safe_load((out / "scan.yaml").read_text())
    assert manifest["schema"] == "scanner.scan/1" and manifest["status"] == "captured"
    assert manifest["sensor"] == "mono" and manifest["object"] == "dtu_small"
    assert manifest["recording"] == {
        "format": "idr",
        "source": str(dtu_small.resolve()),
        "metres_per_unit": 0.001,
        "camera_poses_given": True,
        "masks": True,
        "views": DTU_VIEWS,
    }
    np.testing.assert_array_equal(manifest["X_FC"], np.eye(4))
    scan = open_scan(out)
    assert scan.sensor == "mono" and scan.camera_model is None and scan.views == ()
    assert scan.hangings == (tuple(range(DTU_VIEWS)),)
    assert scan.store.captured_indices() == list(range(DTU_VIEWS))
    rec = read_recording(dtu_small)
    for v in rec.views:
        c = scan.store.read_capture(v.index)
        assert c.sensor == "mono" and c.right is None and c.q_rad.size == 0
        source_rgb = cv2.cvtColor(cv2.imread(str(v.image_path)), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(c.left, source_rgb)  # lossless, RGB like left.png
        assert set(np.unique(c.mask)) <= {0, 255} and 0 < (c.mask == 255).mean() < 1
        np.testing.assert_array_equal(c.X_WC, v.X_WC)
        np.testing.assert_array_equal(c.X_WF, v.X_WC)  # camera poses given: X_WF = X_WC
        np.testing.assert_array_equal(c.camera.K, v.camera.K)
        assert c.stamp_s == v.index
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


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


@pytest.mark.parametrize("binary", [False, True])
def test_colmap_round_trip_with_scale(binary, tmp_path):
    project, X_WC_m = colmap_project(tmp_path, binary)
    rec = read_recording(project, metres_per_unit=COLMAP_UNIT_M)
    assert rec.format == "colmap" and rec.metres_per_unit == COLMAP_UNIT_M
    assert [v.image_path.name for v in rec.views] == [Path(n).name for n in COLMAP_NAMES]
    for v, X_WC in zip(rec.views, X_WC_m, strict=True):
        assert_poses_close(v.X_WC, X_WC)
        np.testing.assert_allclose(v.camera.K, COLMAP_CAMERA.K, atol=1e-12)
        np.testing.assert_allclose(v.camera.distortion, COLMAP_CAMERA.distortion, atol=1e-15)


def test_colmap_scale_from_a_known_distance(tmp_path):
    project, X_WC_m = colmap_project(tmp_path, binary=False)
    d_m = float(np.linalg.norm(X_WC_m[0][:3, 3] - X_WC_m[3][:3, 3]))
    known = KnownDistance(COLMAP_NAMES[0], COLMAP_NAMES[3], d_m)
    rec = read_recording(project, known_distance=known)
    assert rec.metres_per_unit == pytest.approx(COLMAP_UNIT_M, rel=1e-12)
    assert_poses_close(rec.views[2].X_WC, X_WC_m[2])


@pytest.mark.parametrize(
    "model, params, K_row0, distortion",
    [
        ("SIMPLE_PINHOLE", [50, 20.5, 15.5], [50, 0, 20], [0, 0, 0, 0, 0]),
        ("PINHOLE", [50, 52, 20.5, 15.5], [50, 0, 20], [0, 0, 0, 0, 0]),
        ("SIMPLE_RADIAL", [50, 20.5, 15.5, 0.1], [50, 0, 20], [0.1, 0, 0, 0, 0]),
        ("RADIAL", [50, 20.5, 15.5, 0.1, -0.2], [50, 0, 20], [0.1, -0.2, 0, 0, 0]),
        (
            "OPENCV",
            [50, 52, 20.5, 15.5, 0.1, -0.2, 0.01, 0.02],
            [50, 0, 20],
            [0.1, -0.2, 0.01, 0.02, 0],
        ),
    ],
)
def test_colmap_camera_models_map_to_K_and_opencv_distortion(model, params, K_row0, distortion):
    cam = pinhole_of(colmap_model.ColmapCamera(1, model, 40, 30, np.array(params, float)), "t")
    np.testing.assert_allclose(cam.K[0], K_row0)  # COLMAP's cx 20.5 is OpenCV's 20
    assert cam.K[1, 2] == 15.0
    np.testing.assert_allclose(cam.distortion, distortion)


def test_colmap_project_imports_into_a_scan_directory(tmp_path, capfd):
    project, X_WC_m = colmap_project(tmp_path, binary=True)
    (project / "images" / "unregistered.png").write_bytes(
        (project / "images" / COLMAP_NAMES[0]).read_bytes()
    )
    out = tmp_path / "scan"
    r = scanner(capfd, "import-recording", project, "--out", out, "--scale", COLMAP_UNIT_M)
    assert r.returncode == 0, r.stderr
    assert "not registered" in r.stdout and "unregistered.png" in r.stdout
    scan = open_scan(out)
    assert scan.recording.format == "colmap" and not scan.recording.masks
    assert_poses_close(scan.store.read_capture(1).X_WC, X_WC_m[1])


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


def test_plain_flange_poses_give_X_WC_through_X_FC(tmp_path, capfd):
    folder, _, X_WC_m = plain_recording(tmp_path)
    rec = read_recording(folder)
    assert rec.format == "plain" and not rec.camera_poses_given
    for v, X_WC in zip(rec.views, X_WC_m, strict=True):
        assert_poses_close(v.X_WC, v.X_WF @ rec.X_FC)
        np.testing.assert_allclose(v.X_WC, X_WC, atol=1e-12)
    out = tmp_path / "scan"
    r = scanner(capfd, "import-recording", folder, "--out", out)
    assert r.returncode == 0, r.stderr
    scan = open_scan(out)
    assert not scan.recording.camera_poses_given
    np.testing.assert_allclose(scan.X_FC_nominal, rec.X_FC, atol=1e-12)
    c = scan.store.read_capture(2)
    np.testing.assert_allclose(c.X_WF, rec.views[2].X_WF, atol=1e-12)  # the flange pose
    np.testing.assert_allclose(c.X_WC, X_WC_m[2], atol=1e-12)
    assert c.depth.dtype == np.uint16 and int(c.depth[0, 0]) == 502 and c.depth_scale_m == 1e-4
    assert (c.mask == 255).sum() == 10 * 12 and set(np.unique(c.mask)) == {0, 255}


# -- bad input: one line, exit 2, nothing written ---------------------------------------------
def test_idr_more_images_than_cameras_is_refused(dtu_small, tmp_path, capfd):
    folder = copy_of(dtu_small, tmp_path)
    shutil.copy(folder / "images" / "000000.png", folder / "images" / "000099.png")
    err = refused(capfd, folder, tmp_path / "scan")
    assert "4 cameras (world_mat_i), but 5 images" in err


def test_idr_fewer_images_than_cameras_is_refused(dtu_small, tmp_path):
    folder = copy_of(dtu_small, tmp_path)
    (folder / "images" / "000002.png").unlink()
    with pytest.raises(ScannerError, match="4 cameras .world_mat_i., but 3 images"):
        read_recording(folder)


def turned_around(P: np.ndarray) -> np.ndarray:
    """The projection of the same camera turned half a turn about its y axis."""
    K, R_CW, c_h = cv2.decomposeProjectionMatrix(P[:3])[:3]
    R_CW = np.diag([-1.0, 1.0, -1.0]) @ R_CW
    out = P.copy()
    out[:3] = K @ np.column_stack([R_CW, -R_CW @ (c_h[:3, 0] / c_h[3, 0])])
    return out


def _replace_world_mat(folder: Path, i: int, P: np.ndarray) -> None:
    data = dict(np.load(folder / "cameras_sphere.npz"))
    data[f"world_mat_{i}"] = P
    np.savez(folder / "cameras_sphere.npz", **data)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda P: np.where(np.arange(16).reshape(4, 4) == 5, np.nan, P), "expected a finite 3x4"),
        (lambda P: np.vstack([P[:1], P[:1], P[2:]]), "singular"),
        (lambda P: turned_around(P), "behind the camera"),
    ],
    ids=["non-finite", "singular", "behind"],
)
def test_idr_bad_projection_is_refused(change, message, dtu_small, tmp_path):
    folder = copy_of(dtu_small, tmp_path)
    P = np.load(folder / "cameras_sphere.npz")["world_mat_1"].astype(float)
    _replace_world_mat(folder, 1, change(P))
    with pytest.raises(ScannerError, match=message) as e:
        read_recording(folder)
    assert "world_mat_1" in str(e.value)


def test_idr_skewed_camera_is_refused(dtu_small, tmp_path):
    folder = copy_of(dtu_small, tmp_path)
    P = np.load(folder / "cameras_sphere.npz")["world_mat_2"].astype(float)
    shear = np.array([[1, 0.01, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    _replace_world_mat(folder, 2, shear @ P)
    with pytest.raises(ScannerError, match="world_mat_2: K has skew"):
        read_recording(folder)


def test_masks_of_another_count_are_refused(dtu_small, tmp_path, capfd):
    folder = copy_of(dtu_small, tmp_path)
    (folder / "mask" / "003.png").unlink()
    err = refused(capfd, folder, tmp_path / "scan")
    assert "3 mask(s), expected one per image (4" in err


def test_masks_of_another_size_are_refused(dtu_small, tmp_path):
    folder = copy_of(dtu_small, tmp_path)
    masks = tmp_path / "other_masks"
    masks.mkdir()
    for i in range(DTU_VIEWS):
        cv2.imwrite(str(masks / f"m{i}.png"), np.zeros((150, 200), np.uint8))
    with pytest.raises(ScannerError, match=r"m0.png: mask is 200x150 px, expected .* \(400x300\)"):
        read_recording(folder, masks=masks)


def test_images_of_another_size_than_the_camera_are_refused(tmp_path, capfd):
    project, _ = colmap_project(tmp_path, binary=False)
    write_noise_images(project / "images", [COLMAP_NAMES[2]], 80, 60)
    err = refused(capfd, project, tmp_path / "scan", "--scale", "1")
    assert "frame_002.png: image is 80x60 px, the camera of view 2 says 64x48" in err


def test_two_views_at_the_same_pose_are_refused(tmp_path):
    folder, doc, _ = plain_recording(tmp_path, depth=False)
    X = np.array(doc["views"][0]["X_WF"])
    X[0, 3] += 0.5  # 0.5 mm (the file's unit): closer than 1 mm
    doc["views"][1]["X_WF"] = X.tolist()
    (folder / "recording.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ScannerError, match=r"views 0 \(0.png\) and 1 \(1.png\) .* 0.5 mm apart"):
        read_recording(folder)


def test_colmap_without_a_scale_is_refused(tmp_path, capfd):
    project, _ = colmap_project(tmp_path, binary=True)
    err = refused(capfd, project, tmp_path / "scan")
    assert "a COLMAP model has no unit" in err and "--known-distance" in err


@pytest.mark.parametrize("binary", [False, True])
def test_unknown_colmap_camera_model_is_refused(binary, tmp_path):
    cam = colmap_model.ColmapCamera(1, "FOV", 64, 48, np.array([70.0, 72, 32, 24, 0.1]))
    project, _ = colmap_project(tmp_path, binary, camera=cam)
    with pytest.raises(ScannerError, match="uses the COLMAP model FOV; expected PINHOLE"):
        read_recording(project, metres_per_unit=1.0)


def test_unnamed_colmap_camera_model_is_refused(tmp_path):
    project, _ = colmap_project(tmp_path, binary=False)
    cameras = project / "sparse" / "0" / "cameras.txt"
    cameras.write_text(cameras.read_text().replace("OPENCV", "BROWN_CONRADY"))
    with pytest.raises(ScannerError, match="cameras.txt:3: unknown COLMAP camera model 'BROWN"):
        read_recording(project, metres_per_unit=1.0)


def test_an_out_folder_that_is_not_empty_is_refused(tmp_path, capfd):
    folder, _, _ = plain_recording(tmp_path, depth=False)
    out = tmp_path / "scan"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = scanner(capfd, "import-recording", folder, "--out", out)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "is not empty (it holds notes.txt)" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    # An earlier import is not replaced either (there is no --force).
    r = scanner(capfd, "import-recording", folder, "--out", tmp_path / "first")
    assert r.returncode == 0, r.stderr
    before = (tmp_path / "first" / "scan.yaml").read_bytes()
    r = scanner(capfd, "import-recording", folder, "--out", tmp_path / "first")
    assert r.returncode == 2 and "is not empty" in r.stderr
    assert (tmp_path / "first" / "scan.yaml").read_bytes() == before


def test_scale_and_format_options_are_checked(tmp_path, capfd):
    folder, _, _ = plain_recording(tmp_path, depth=False)
    with pytest.raises(ScannerError, match="--scale: the plain form states its unit"):
        read_recording(folder, metres_per_unit=0.001)
    project, _ = colmap_project(tmp_path, binary=False)
    known = KnownDistance(COLMAP_NAMES[0], "nope.png", 1.0)
    with pytest.raises(ScannerError, match="--known-distance: no image named 'nope.png'"):
        read_recording(project, known_distance=known)
    with pytest.raises(ScannerError, match="give one of them, not both"):
        read_recording(project, metres_per_unit=1.0, known_distance=known)
    (project / "recording.yaml").write_text("unit_m: 1\n")
    with pytest.raises(ScannerError, match="holds the files of colmap and plain; choose one"):
        read_recording(project)
    out = tmp_path / "scan"
    for distance in ("0", "-1", "nan", "ten"):
        r = scanner(capfd, "import-recording", project, "--out", out, "--format", "colmap",
                    "--known-distance", COLMAP_NAMES[0], COLMAP_NAMES[1], distance)  # fmt: skip
        assert r.returncode == 2 and "--known-distance: expected a distance in metres" in r.stderr
        assert not out.exists()


def test_commands_for_scans_of_the_cell_refuse_an_imported_recording(tmp_path, capfd):
    folder, _, _ = plain_recording(tmp_path, depth=False)
    out = tmp_path / "scan"
    assert scanner(capfd, "import-recording", folder, "--out", out).returncode == 0
    for command in (["reconstruct", out], ["scan", "--resume", out]):
        r = scanner(capfd, *command)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "is an imported recording (plain, sensor mono)" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["captures", "scan.yaml"]


def test_a_failure_while_writing_leaves_nothing(tmp_path, capfd, monkeypatch):
    import scanner.recordings.scan_writer as writer

    folder, _, _ = plain_recording(tmp_path, depth=False)
    read = writer.read_image_rgb

    def fails_on_the_third(path):
        if path.name == "2.png":
            raise ScannerError(f"{path}: unreadable (simulated)")
        return read(path)

    monkeypatch.setattr(writer, "read_image_rgb", fails_on_the_third)
    err = refused(capfd, folder, tmp_path / "scan")
    assert "2.png: unreadable (simulated)" in err
