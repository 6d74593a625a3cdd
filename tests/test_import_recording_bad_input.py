"""`scanner import-recording` refuses every bad input in one line naming the file and what was
expected (exit 2), and writes nothing: missing or extra images, images of another size than
their camera, bad projections, masks that do not match, two views at one pose, a COLMAP model
without a scale or with an unsupported camera model, a non-empty --out."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from reconstruction.recordings import colmap_model
from reconstruction.recordings.colmap import KnownDistance
from reconstruction.recordings.formats import read_recording
from tests.in_process import scanner
from tests.recording_files import (
    COLMAP_NAMES,
    DTU_VIEWS,
    colmap_project,
    copy_of,
    dtu_small_folder,
    plain_recording,
    refused,
    write_noise_images,
)


@pytest.fixture(scope="module")
def dtu_small(tmp_path_factory) -> Path:
    return dtu_small_folder(tmp_path_factory.mktemp("idr"))


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


def test_resume_refuses_an_imported_recording_and_unpaired_views_are_one_line(tmp_path, capfd):
    folder, _, _ = plain_recording(tmp_path, depth=False)
    out = tmp_path / "scan"
    assert scanner(capfd, "import-recording", folder, "--out", out).returncode == 0
    r = scanner(capfd, "scan", "--resume", out)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "is an imported recording (plain, sensor mono)" in r.stderr
    # Reconstructed as a recording: these views stand 40 deg apart, too far to pair.
    r = scanner(capfd, "reconstruct", out)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "pairing: view 0 has no partner within the limits" in r.stderr
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
