"""A real robot-arm recording (DTU's scan 24: one camera on an industrial arm) reconstructed by
`scanner reconstruct`: pairs of the camera's views, the working volume from the masks or the
cameras' common view, the table found in the data, and the measures without a reference
surface. Eight views at a quarter of the resolution (the whole set: scripts/bench_recordings.py).
"""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from scanner.commands.main import main
from scanner.commands.reconstruct import reconstruct_saved
from scanner.reconstruct.command import ReconstructOptions
from tests.in_process import scanner
from tests.recording_files import dtu_small_folder

VIEWS = 8
DTU_CENTRE_M = (-0.02846, -0.01319, 0.64149)


@pytest.fixture(scope="module")
def dtu_scan(tmp_path_factory):
    parent = tmp_path_factory.mktemp("dtu")
    folder = dtu_small_folder(parent, VIEWS)
    out = parent / "scan"
    assert main(["import-recording", str(folder), "--out", str(out)]) == 0
    # The views are downscaled already: matched as they are.
    (parent / "settings.yaml").write_text("two_view:\n  downscale: 1.0\n")
    return out


def _run(dtu_scan, masks: str, out):
    settings = dtu_scan.parent / "settings.yaml"
    return reconstruct_saved(dtu_scan, ReconstructOptions(config=settings, masks=masks, out=out))


@pytest.fixture(scope="module")
def even_masks(dtu_scan, tmp_path_factory):
    return _run(dtu_scan, "even", tmp_path_factory.mktemp("even") / "results")


@pytest.fixture(scope="module")
def no_masks(dtu_scan, tmp_path_factory):
    return _run(dtu_scan, "none", tmp_path_factory.mktemp("none") / "results")


def test_the_model_agrees_with_the_masks_it_did_not_use(even_masks):
    r = even_masks.report
    assert r["recording"]["handeye"] == "not run: the recording gave camera poses"
    pairs = [(p["reference"], p["other"]) for p in r["pairs"]]
    # Each view the reference of two pairs, its nearest partner first (the arm's neighbour).
    assert [i for i, _ in pairs] == [i for i in range(VIEWS) for _ in range(2)]
    assert pairs[0::2][:2] == [(0, 1), (1, 0)] and all(i != j for i, j in pairs)
    assert len(set(pairs)) == len(pairs)
    # Calibrated poses: within the limit above which a pair's pose is refined.
    assert all(p["epipolar_median_px"] < 1.0 for p in r["pairs"]) and r["pairs_refined"] == 0
    s = r["silhouette"]
    assert s["held_out"] and s["views"] == [1, 3, 5, 7]
    # Measured: IoU 0.83 (worst 0.79), 0.85 of the mask covered; 8 of 49 views at a quarter
    # resolution see part of the house only (all 49 at half: 0.977 and 0.989, the benchmark).
    assert s["mesh"]["iou_median"] > 0.78 and s["mesh"]["coverage_median"] > 0.8
    # Measured 0.63 mm median on 93 % of the points: a quarter-resolution pixel is 0.9 mm.
    h = r["split_half"]
    assert h["common_share"] > 0.85 and h["median_mm"] < 0.9
    # Along the other half's surface normal the samplings' spacing drops out: nearer.
    assert 0.0 < h["normal_median_mm"] < h["median_mm"] and h["normal_p90_mm"] < h["p90_mm"]
    folder = even_masks.results_dir
    assert json.loads((folder / "report.json").read_text())["split_half"] == h
    for name in ("fused_cloud.ply", "mesh_poisson.ply", "summary.md", "reconstruction.yaml"):
        assert (folder / name).stat().st_size > 0, name
    # The 3D page, as for a scan: the model and the views' frustums (no cell, no arm).
    assert r["model_page"] == "model.html" and (folder / "model.html").stat().st_size > 10_000
    summary = (folder / "summary.md").read_text()
    assert "views whose masks the model did not use" in summary
    assert "Hand-eye correction: not run" in summary
    from scanner.reconstruct.command import summary_lines

    printed = "\n".join(summary_lines(r))
    assert "silhouettes on 4 held-out views: IoU" in printed and "split-half agreement" in printed


def test_the_models_picture_has_the_colours_of_its_images(even_masks, dtu_scan):
    """model_colours.png shows the model in the colours taken from the images: the mean
    chromaticity of what it shows is that of the masked image pixels (a red-brick house: red
    ahead of blue; with the channels swapped it would be blue ahead of red)."""
    import cv2

    from scanner.scan_dir.manifest import open_scan

    folder = even_masks.results_dir
    assert even_masks.report["outputs"]["colour_picture"] == "model_colours.png"
    assert "(model_colours.png)" in (folder / "summary.md").read_text()
    picture = cv2.imread(str(folder / "model_colours.png"))[..., ::-1].astype(float)
    assert picture.shape == (480, 960, 3)
    shown = np.any(np.abs(picture - picture[-1, -1]) > 12, axis=2)
    shown[:40] = False  # the labels
    assert 0.05 < shown.mean() < 0.9
    saved = open_scan(dtu_scan)
    total, count = np.zeros(3), 0
    for i in saved.store.captured_indices():
        capture = saved.store.read_capture(i)
        inside = np.asarray(capture.mask) > 0
        total += np.asarray(capture.left)[inside].astype(float).sum(axis=0)
        count += inside.sum()
    chroma_images = total / count / (total / count).sum()
    mean = picture[shown].mean(axis=0)
    chroma_picture = mean / mean.sum()
    # Measured: images (0.377, 0.319, 0.304), picture (0.356, 0.326, 0.319); the shading is
    # white light, which keeps the chromaticity but for the grey of shadows.
    assert np.abs(chroma_picture - chroma_images).max() < 0.03
    assert chroma_picture[0] - chroma_picture[2] > 0.25 * (chroma_images[0] - chroma_images[2])


def test_the_working_volume_comes_from_the_masks_or_the_cameras(even_masks, no_masks):
    hull, common = even_masks.report["working_volume"], no_masks.report["working_volume"]
    assert common["source"] == "common view"
    # The hull of views from one side is open in depth: its sphere, centred on the masks and not
    # capped by the common view's, comes out about as large as the common view's.
    assert hull["source"] == "masks" and hull["radius_m"] < 1.3 * common["radius_m"]
    # DTU's own sphere about the scene (scale_mat): centre (-28.5, -13.2, 641.5) mm, radius
    # 231 mm. Both volumes lie about the same place and are of its size.
    for volume in (hull, common):
        assert np.linalg.norm(np.subtract(volume["centre_m"], DTU_CENTRE_M)) < 0.231 / 2
        assert 0.1 < volume["radius_m"] < 0.3


def test_without_masks_every_masked_view_scores_the_model(no_masks):
    r = no_masks.report
    s = r["silhouette"]
    assert s["held_out"] and s["views"] == list(range(VIEWS))
    # The white table gives stereo nothing to match (no table is found in the data); what the
    # working volume alone keeps is the house and some of the dark background. Measured: 0.88
    # of the mask covered, IoU 0.54.
    assert r["table"] is None
    assert (
        s["mesh"]["coverage_median"] > 0.8
        and s["mesh"]["iou_median"] < s["mesh"]["coverage_median"]
    )
    assert "Working volume from common view" in (no_masks.results_dir / "summary.md").read_text()


def test_recording_options_are_refused_where_they_do_not_apply(
    dtu_scan, tiny_scan, tmp_path, capfd
):
    with pytest.raises(ScannerError, match="--calibration: .* imported recording"):
        reconstruct_saved(dtu_scan, ReconstructOptions(calibration=tmp_path / "c.yaml"))
    with pytest.raises(ScannerError, match="--masks: only for an imported recording"):
        reconstruct_saved(tiny_scan.scan_dir, ReconstructOptions(masks="even"))
    capfd.readouterr()
    out = tmp_path / "r"
    code = main(
        ["reconstruct", str(dtu_scan), "--volume", "0", "0", "0.6", "-1", "--out", str(out)]
    )
    err = capfd.readouterr().err
    assert code == 2 and "--volume" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


# Spheres of different sizes, off each other's centres: a shape with no symmetry, which holds a
# registration (one sphere turns on itself) and so the hand-eye correction. Centres and radii, m.
BLOBS = np.array(
    [
        [0.0, 0.0, 0.0, 0.05],
        [0.045, 0.025, 0.02, 0.03],
        [-0.03, 0.045, -0.025, 0.028],
        [0.0, -0.045, 0.035, 0.022],
        [-0.04, -0.02, -0.03, 0.02],
    ]
)


def depth_of_spheres(
    X_WC: np.ndarray, K: np.ndarray, size: tuple[int, int], spheres: np.ndarray = BLOBS
) -> np.ndarray:
    """Depth along the optical axis (m, 0 where no sphere is hit) of the nearest of `spheres`
    (rows: centre x, y, z and radius, metres)."""
    w, h = size
    v, u = np.mgrid[0:h, 0:w]
    rays_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)
    rays_W = rays_C @ X_WC[:3, :3].T
    a2 = np.einsum("ijk,ijk->ij", rays_W, rays_W)
    z = np.full((h, w), np.inf)
    for cx, cy, cz, r in spheres:
        # |o + t d|^2 = r^2 along each ray d (not unit: t is the depth z).
        o = X_WC[:3, 3] - (cx, cy, cz)
        b = 2 * rays_W @ o
        disc = b**2 - 4 * a2 * (o @ o - r**2)
        t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a2)
        z = np.where((disc > 0) & (t > 0) & (t < z), t, z)
    return np.where(np.isfinite(z), z, 0.0)


def _depth_recording(
    folder: Path, K: np.ndarray, size, X_FC_true, X_FC_given, X_WCs, spheres=BLOBS
) -> Path:
    """A plain recording in `folder` (flange poses, the given X_FC, 16-bit depth images of
    `spheres` in 0.1 mm units beside random colour images), imported: the scan directory."""
    import cv2
    import yaml

    from reconstruction.common.transforms import invert

    folder.mkdir()
    w, h = size
    rng = np.random.default_rng(0)
    views = []
    for i, X_WC in enumerate(X_WCs):
        z = depth_of_spheres(X_WC, K, (w, h), spheres)
        cv2.imwrite(str(folder / f"d{i}.png"), np.round(z / 1e-4).astype(np.uint16))
        cv2.imwrite(str(folder / f"i{i}.png"), rng.integers(0, 255, (h, w, 3), np.uint8))
        X_WF = X_WC @ invert(X_FC_true)
        views.append({"image": f"i{i}.png", "X_WF": X_WF.tolist(), "depth": f"d{i}.png"})
    doc = {"unit_m": 1.0, "K": K.tolist(), "X_FC": X_FC_given.tolist(), "depth_unit_m": 1e-4}
    (folder / "recording.yaml").write_text(yaml.safe_dump({**doc, "views": views}))
    scan = folder.parent / "scan"
    assert main(["import-recording", str(folder), "--out", str(scan)]) == 0
    return scan


def test_views_with_depth_images_go_through_the_depth_path(tmp_path, capfd):
    """A plain recording whose views carry 16-bit depth images of a known sphere (flange poses
    and X_FC, depth in 0.1 mm units): no pairs, every view its own depth cloud, and the model on
    the sphere."""
    from reconstruction.common.transforms import make_pose
    from tests.recording_files import look_at

    centre, radius, f, (w, h) = np.zeros(3), 0.1, 200.0, (240, 180)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    X_FC = make_pose(np.eye(3), (0.01, -0.02, 0.1))
    X_WCs = [
        look_at((0.5 * np.cos(a), 0.5 * np.sin(a), 0.2))
        for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)
    ]
    spheres = np.array([[*centre, radius]])
    scan = _depth_recording(tmp_path / "sphere", K, (w, h), X_FC, X_FC, X_WCs, spheres)
    # A sphere does not hold a registration (it turns on itself): the depth path is what is
    # tested, with the poses as recorded.
    options = ReconstructOptions(out=tmp_path / "results", no_icp=True, no_handeye=True)
    run = reconstruct_saved(scan, options)
    r = run.report
    assert r["pairs"] == [] and r["depth_views"] == 6
    assert r["recording"]["camera_poses_given"] is False
    # On the sphere: 0.1 mm depth steps; the fused voxel is two 2.5 mm footprints at 0.5 m,
    # e = 5 mm, and voxel centroids of a convex surface lie inside it by a fraction of
    # e^2 / r = 0.25 mm.
    fused = run.result.fused.points_W
    signed = np.linalg.norm(fused - centre, axis=1) - radius
    assert len(fused) > 500
    assert -0.25e-3 < np.median(signed) < 0 and np.percentile(np.abs(signed), 95) < 0.5e-3


@dataclass(frozen=True, eq=False)
class BlobsRecording:
    scan: Path
    X_FC_true: np.ndarray
    X_FC_given: np.ndarray


@pytest.fixture(scope="module")
def blobs(tmp_path_factory) -> BlobsRecording:
    """A plain recording of flange poses and an X_FC 3 mm / 1 deg off the camera's true mount,
    with depth images of BLOBS from 24 views around them (twelve fewer leave the correction
    unconverged: sigma 1.8 mm)."""
    import cv2

    from reconstruction.common.transforms import make_pose
    from tests.recording_files import look_at

    tmp_path = tmp_path_factory.mktemp("blobs")
    f, (w, h) = 600.0, (480, 360)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    X_FC_true = make_pose(np.eye(3), (0.01, -0.02, 0.1))
    tilt = 1.0 * np.pi / 180 / np.sqrt(2)
    R_off = cv2.Rodrigues(np.array([tilt, -tilt, 0.0]))[0]
    X_FC_given = make_pose(R_off @ X_FC_true[:3, :3], X_FC_true[:3, 3] + (0.002, 0.002, -0.001))
    stations = [(a, 0.2) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
    stations += [(a + 0.26, -0.15) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
    X_WCs = []
    for i, (a, height) in enumerate(stations):
        X_WC = look_at((0.45 * np.cos(a), 0.45 * np.sin(a), height))
        # Rolled about the optical axis by a different angle each: the flange turns about
        # more than one axis between views, which the hand-eye problem needs.
        X_WCs.append(
            X_WC @ make_pose(cv2.Rodrigues(np.array([0.0, 0.0, 0.13 * i - 1.5]))[0], (0, 0, 0))
        )
    scan = _depth_recording(tmp_path / "recording", K, (w, h), X_FC_true, X_FC_given, X_WCs)
    return BlobsRecording(scan, X_FC_true, X_FC_given)


def _mount_error(X_FC_true: np.ndarray, X_FC: np.ndarray) -> tuple[float, float]:
    """mm, deg."""
    from reconstruction.common.transforms import invert

    d = invert(X_FC_true) @ X_FC
    angle = np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))
    return 1e3 * float(np.linalg.norm(d[:3, 3])), float(np.degrees(angle))


def test_flange_poses_with_a_rough_X_FC_get_the_hand_eye_correction(blobs, tmp_path):
    """The hand-eye correction runs on a recording of flange poses as on a scan, and brings
    the recorded X_FC towards the camera's true mount."""
    run = reconstruct_saved(blobs.scan, ReconstructOptions(out=tmp_path / "results"))
    r = run.report
    assert r["recording"]["camera_poses_given"] is False
    assert r["recording"]["handeye"] == "run"
    before = _mount_error(blobs.X_FC_true, blobs.X_FC_given)
    after = _mount_error(blobs.X_FC_true, run.result.X_FC)
    print("mount error before, after (mm, deg):", before, after)
    diagnosis = run.result.handeye.diagnosis
    assert diagnosis.converged
    # Within the accuracy the correction claims (3 sigma), and well inside where it started.
    assert after[0] < 3e3 * diagnosis.sigma_translation_m
    assert after[1] < 3 * np.degrees(diagnosis.sigma_rotation_rad)
    assert after[0] < before[0] / 3 and after[1] < before[1] / 3
    # Noise-free depth: measured 0.02 mm / 0.001 deg.
    assert after[0] < 0.1 and after[1] < 0.02


def test_a_box_given_as_the_volume_keeps_only_what_lies_in_it(blobs, tmp_path, capfd):
    """--box: the fused points all lie in it, and the box cuts
    the blob that sticks out on +x; the report and summary say it was a given box."""
    box = (-0.06, -0.08, -0.07, 0.03, 0.08, 0.07)
    out = tmp_path / "results"
    argv = ["reconstruct", str(blobs.scan), "--out", str(out), "--no-icp", "--no-handeye"]
    assert main([*argv, "--box", *map(str, box)]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["working_volume"]["source"] == "given box"
    np.testing.assert_allclose(r["working_volume"]["half_extent_m"], [0.045, 0.08, 0.07])
    assert "a box of 90.0 x 160.0 x 140.0 mm" in (out / "summary.md").read_text()
    import open3d as o3d

    fused = np.asarray(o3d.io.read_point_cloud(str(out / r["outputs"]["fused_cloud"])).points)
    assert len(fused) > 500
    assert np.all(fused >= np.array(box[:3]) - 1e-9) and np.all(fused <= np.array(box[3:]) + 1e-9)
    # The +x blob (centre x 0.045, radius 0.03) reached x = 0.075 m: cut at the box's 0.03 m.
    assert fused[:, 0].max() > 0.025


def test_a_bad_box_or_a_box_and_a_sphere_are_refused(blobs, tmp_path, capfd):
    out = tmp_path / "results"
    r = scanner(capfd, "reconstruct", blobs.scan, "--out", out, "--box", "0", "0", "0")
    assert r.returncode == 2 and "--box: expected 6 arguments" in r.stderr
    r = scanner(
        capfd, "reconstruct", blobs.scan, "--out", out, "--box", "0", "0", "0", "0", "1", "1"
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "--box: each maximum must exceed its minimum" in r.stderr
    both = ["--box", "0", "0", "0", "1", "1", "1", "--volume", "0", "0", "0", "1"]
    r = scanner(capfd, "reconstruct", blobs.scan, "--out", out, *both)
    assert r.returncode == 2 and "--box, --volume: give the sphere or the box, not both" in r.stderr
    # The scan directory may follow the options (the box takes exactly six numbers).
    r = scanner(capfd, "reconstruct", "--box", "0", "0", "0", "0", "1", "1", blobs.scan)
    assert r.returncode == 2 and "--box: each maximum must exceed its minimum" in r.stderr
    assert not out.exists()
