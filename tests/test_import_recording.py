"""`scanner import-recording`: recordings of other systems (IDR/NeuS, COLMAP, the plain form)
become scan directories with the poses, cameras, images and masks of the source.

The IDR tests use four DTU MVS scan 24 views downscaled by 4 (P scaled to match); COLMAP and
the plain form are synthetic, with known poses (tests/recording_files.py)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from reconstruction.common.transforms import invert
from reconstruction.recordings import colmap_model
from reconstruction.recordings.colmap import KnownDistance, pinhole_of
from reconstruction.recordings.formats import read_recording
from scanner.scan_dir.manifest import open_scan
from tests.in_process import scanner
from tests.recording_files import (
    COLMAP_CAMERA,
    COLMAP_NAMES,
    COLMAP_UNIT_M,
    DOWNSCALE,
    DTU_CX_PX,
    DTU_CY_PX,
    DTU_FX_PX,
    DTU_FY_PX,
    DTU_P_WC0_M,
    DTU_VIEWS,
    assert_poses_close,
    colmap_project,
    dtu_small_folder,
    plain_recording,
)


@pytest.fixture(scope="module")
def dtu_small(tmp_path_factory) -> Path:
    return dtu_small_folder(tmp_path_factory.mktemp("idr"))


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
