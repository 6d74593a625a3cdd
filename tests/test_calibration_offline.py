"""`scanner calibrate --offline`: the real Open3DV circle-grid set, bad input, CLI exit codes.

The commands run in the test's process (`tests.in_process`); one calibration of the whole set
(with --robot-offsets, which these poses without joint angles leave out) is read by the tests
about its result."""

import json
import math
import shutil

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.file import load_calibration
from reconstruction.calibration.pose_files import pose_format
from reconstruction.common.errors import RefusedResultError, ScannerError
from scanner.calibrate.offline import OfflineOptions, calibrate_directory
from tests.conftest import shared_data
from tests.in_process import scanner, scanner_in_fixture

REAL = "real/handeye_open3dv_eye_in_hand_circlegrid"
# The data set's README: reference = OpenCV TSAI/PARK; a test should find the rotation within
# ~0.5 deg, the translation within ~5-10 mm (weakly observable: all poses at one height, tilts
# <= 13 deg) and a board-in-base scatter under ~1-2 mm.
REFERENCE_T_M = np.array([219.96, 68.97, -177.71]) * 1e-3  # TSAI
REFERENCE_ROTVEC = np.array([0.1004, -0.0459, 1.5495])
ROTATION_TOL_RAD = math.radians(0.5)
TRANSLATION_TOL_M = 5e-3
SCATTER_TOL_M = 1e-3
BOARD_ARGS = [
    "--board",
    "circles_asymmetric",
    "--board-size",
    "7x11",
    "--board-spacing",
    "0.02",
    "--inverted",
]


def _options(root):
    return OfflineOptions(
        BoardSpec("circles_asymmetric", 7, 11, 0.02, inverted=True),
        pose_format("open3dv"),
        intrinsics=root / "param.txt",
    )


def _open3dv_args(data, intrinsics_root, out, *extra) -> list:
    """`scanner calibrate --offline` on Open3DV-style data with its board and convention."""
    return [
        "calibrate",
        "--offline",
        data,
        *BOARD_ARGS,
        "--pose-convention",
        "open3dv",
        "--intrinsics",
        intrinsics_root / "param.txt",
        *extra,
        "--out",
        out,
    ]


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """The whole set calibrated with --robot-offsets: (the output folder, the command's run)."""
    root = shared_data(REAL)
    out = tmp_path_factory.mktemp("open3dv")
    r = scanner_in_fixture(*_open3dv_args(root, root, out, "--robot-offsets"))
    assert r.returncode == 0, r.stderr
    return out, r


def test_real_circle_grid_matches_the_reference(real_run):
    out, r = real_run
    calibration = load_calibration(out / "results" / "calibration.yaml")
    assert calibration.stereo is None and calibration.camera.width == 1920
    X = calibration.X_FC
    R_ref = Rotation.from_rotvec(REFERENCE_ROTVEC).as_matrix()
    angle = Rotation.from_matrix(X[:3, :3].T @ R_ref).magnitude()
    assert angle < ROTATION_TOL_RAD
    assert np.linalg.norm(X[:3, 3] - REFERENCE_T_M) < TRANSLATION_TOL_M
    assert max(calibration.quality["board_scatter_m"]) < SCATTER_TOL_M
    assert calibration.quality["poses_used"] == 8
    assert "calibration: 8/8 poses used" in r.stdout


def test_wrong_euler_convention_is_refused_with_the_convention_that_fits(tmp_path):
    """A wrong convention gives a scatter of centimetres: refused, nothing written, and the
    message names the preset the data fit."""
    root = shared_data(REAL)
    options = _options(root)
    wrong = OfflineOptions(
        options.board, pose_format("open3dv", euler="XYZ"), intrinsics=options.intrinsics
    )
    with pytest.raises(RefusedResultError, match="board-in-base scatter") as e:
        calibrate_directory(root, wrong, out_dir=tmp_path)
    assert "--pose-convention open3dv best" in str(e.value)
    assert not (tmp_path / "results").exists()


def test_wrong_preset_exits_3_without_library_noise(tmp_path, capfd):
    root = shared_data(REAL)
    args = ["calibrate", "--offline", root, *BOARD_ARGS, "--intrinsics", root / "param.txt"]
    r = scanner(capfd, *args, "--pose-convention", "kuka", "--out", tmp_path / "out")
    assert r.returncode == 3, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "calibration refused" in lines[0], r.stderr
    assert "--pose-convention open3dv" in lines[0] and "reprojection RMS" in lines[0]
    assert "[ERROR" not in r.stderr and "Traceback" not in r.stderr  # OpenCV's log is off
    assert not (tmp_path / "out" / "results").exists()
    assert not list((tmp_path / "out").glob(".results.partial-*"))


def test_offline_calibration_never_replaces_an_earlier_one(real_run, tmp_path, capfd):
    root = shared_data(REAL)
    out = tmp_path / "out"
    shutil.copytree(real_run[0], out)  # a folder holding a calibration
    first = (out / "results" / "calibration.yaml").read_bytes()
    r = scanner(capfd, *_open3dv_args(root, root, out))
    assert r.returncode == 2 and "holds a calibration already" in r.stderr
    assert (out / "results" / "calibration.yaml").read_bytes() == first
    r = scanner(capfd, *_open3dv_args(root, root, out), "--force")
    assert r.returncode == 0, r.stderr
    # Replaced by this run's: the same data without --robot-offsets (which these poses leave
    # out) gives the same X_FC.
    X_FC = load_calibration(out / "results" / "calibration.yaml").X_FC
    first_X_FC = load_calibration(real_run[0] / "results" / "calibration.yaml").X_FC
    assert np.allclose(X_FC, first_X_FC, atol=1e-9)
    assert "robot_errors" not in json.loads((out / "results" / "report.json").read_text())


def _copy(root, tmp_path, names):
    folder = tmp_path / "data"
    folder.mkdir()
    for name in names:
        for suffix in (".bmp", ".txt"):
            shutil.copy(root / f"{name}{suffix}", folder / f"{name}{suffix}")
    shutil.copy(root / "param.txt", folder / "param.txt")
    return folder


def test_board_not_found_is_skipped_and_reported(tmp_path):
    root = shared_data(REAL)
    folder = _copy(root, tmp_path, [f"pos{i}" for i in range(8)])
    image = cv2.imread(str(folder / "pos5.bmp"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(folder / "pos5.bmp"), np.zeros_like(image))  # lens cap on
    options = _options(folder)
    run = calibrate_directory(folder, options, out_dir=tmp_path / "out")
    assert run.report["poses_board_not_found"] == ["pos5"]
    assert run.report["poses_used"] == 7
    assert run.report["board_not_found_reasons"]["pos5"].startswith("no contrast")
    text = (tmp_path / "out" / "results" / "report.txt").read_text()
    assert "board not found in: pos5 (no contrast" in text


def test_too_few_poses_is_a_clear_error(tmp_path, capfd):
    root = shared_data(REAL)
    folder = _copy(root, tmp_path, ["pos0", "pos1", "pos2"])
    with pytest.raises(ScannerError, match=r"only 3 of 3 poses .* record 2 more pose"):
        calibrate_directory(folder, _options(folder), out_dir=tmp_path / "out")
    r = scanner(capfd, *_open3dv_args(folder, folder, tmp_path / "o"))
    assert r.returncode == 2
    assert "record 2 more pose" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def _fake_folder(tmp_path, pose_text):
    folder = tmp_path / "fake"
    folder.mkdir()
    cv2.imwrite(str(folder / "view0.png"), np.full((48, 64), 255, np.uint8))
    (folder / "view0.txt").write_text(pose_text)
    return folder


@pytest.mark.parametrize(
    "pose_text, flags, needle",
    [
        ("1 2 3 4 5\n", ["--pose-convention", "kuka"], "found 5 numbers, the pose layout"),
        ("1 2 3 4 5 6\n", ["--pose-convention", "robotco"], "unknown pose convention 'robotco'"),
        ("1 2 3 4 5 6\n", ["--pose-layout", "xyz_euler", "--euler", "abc"], "unknown Euler"),
        ("1 2 3 4 5 6\n", ["--pose-layout", "xyz_euler", "--length-unit", "inch"], "length unit"),
        (
            "1 2 3 4 5 6\n",
            ["--pose-layout", "xyz_euler", "--board", "dots"],
            "'dots' is not one of",
        ),
    ],
)
def test_bad_pose_input_is_one_line_exit_2(tmp_path, capfd, pose_text, flags, needle):
    folder = _fake_folder(tmp_path, pose_text)
    board = [] if "--board" in flags else BOARD_ARGS
    r = scanner(capfd, "calibrate", "--offline", folder, *board, *flags, "--out", tmp_path / "out")
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_pose_list_with_wrong_column_count(tmp_path, capfd):
    folder = _fake_folder(tmp_path, "")
    (folder / "view0.txt").unlink()
    poses = tmp_path / "poses.csv"
    poses.write_text("0.1, 0.2, 0.3, 0, 0\n")
    r = scanner(
        capfd,
        "calibrate",
        "--offline",
        folder,
        *BOARD_ARGS,
        "--pose-layout",
        "xyz_rotvec",
        "--pose-file",
        poses,
        "--out",
        tmp_path / "out",
    )
    assert r.returncode == 2
    assert "poses.csv line 1: 5 columns, the pose layout 'xyz_rotvec' needs 6" in r.stderr


def test_planned_mover_executes_or_reports_the_failure():
    from types import SimpleNamespace

    from planners.planner import PlanFailure
    from scanner.calibrate.eye_in_hand import PlannedMover

    executed = []
    robot = SimpleNamespace(
        joint_positions=lambda: np.zeros(6),
        execute=lambda trajectory: executed.append(trajectory),
        motion="joint_linear",
    )

    def planner(result, executable=lambda t, motion: f"{t} as {motion}"):
        return SimpleNamespace(plan=lambda q0, q1: result, executable=executable)

    mover = PlannedMover(planner("trajectory"), robot)
    assert mover(np.ones(6)) and executed == ["trajectory as joint_linear"]
    failure = PlanFailure("no_path", "roadmap disconnected")
    mover = PlannedMover(planner(failure), robot)
    assert not mover(np.ones(6)) and mover.last_failure == "no_path: roadmap disconnected"
    # A path the controller would run differently from the plan, failing its own check
    refused = PlanFailure("validation_failed", "joint-linear path: collision")
    mover = PlannedMover(planner("trajectory", lambda t, m: refused), robot)
    assert not mover(np.ones(6)) and "joint-linear path" in mover.last_failure
    assert executed == ["trajectory as joint_linear"]


def test_real_data_reports_held_out_prediction_for_every_method(real_run):
    """The 8 real poses: held-out prediction (5-fold) of the chosen X_FC and of each of
    OpenCV's methods, printed and in the report; --robot-offsets on poses without joint
    angles says why nothing was estimated and calibrates without them (not a failure)."""
    out, r = real_run
    report = json.loads((out / "results" / "report.json").read_text())
    held = report["held_out"]
    assert held["folds"] == "5-fold"
    assert set(held["methods"]) == {"tsai", "park", "horaud", "andreff", "daniilidis"}
    # Robot errors of about a millimetre dominate this set: held-out is px, not tenths.
    assert 0.5 < held["rms_px"] < 5 and report["held_out_mm"] == pytest.approx(held["rms_mm"])
    line = next(x for x in r.stdout.splitlines() if x.startswith("held-out prediction (5-fold)"))
    assert all(name in line for name in held["methods"])
    assert "robot errors not estimated: the poses carry no joint angles" in r.stdout
    assert report["robot_errors"]["kept"] is False
    assert load_calibration(out / "results" / "calibration.yaml").robot is None
    sources = report["X_FC_sigma_sources"]
    assert sources["reported_mm"] >= max(sources["covariance_mm"], sources["bootstrap_mm"])


def test_fewer_than_six_views_are_held_out_one_at_a_time(tmp_path, capfd):
    root = shared_data(REAL)
    data = tmp_path / "five"
    data.mkdir()
    for k in range(5):
        for suffix in (".bmp", ".txt"):
            shutil.copy(root / f"pos{k}{suffix}", data / f"pos{k}{suffix}")
    r = scanner(capfd, *_open3dv_args(data, root, tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "out" / "results" / "report.json").read_text())
    assert report["held_out"]["folds"] == "leave-one-out over 5 views"
    assert "held out one at a time (leave-one-out)" in r.stdout


def test_robot_offsets_do_not_apply_to_eye_to_hand(tmp_path, capfd):
    r = scanner(capfd, "calibrate", "--eye-to-hand", "--robot-offsets", "--out", tmp_path)
    assert r.returncode == 2
    assert (
        r.stderr.strip()
        .splitlines()[-1]
        .endswith("--robot-offsets applies to eye-in-hand calibrations, not --eye-to-hand")
    )
    assert "Traceback" not in r.stderr
