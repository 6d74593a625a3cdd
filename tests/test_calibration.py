"""Calibration maths without the simulator: boards, projection, hand-eye, pose files, files."""

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reconstruction.calibration.boards import BoardSpec, board_image, detect_board
from reconstruction.calibration.eye_in_hand import calibrate_hand_eye
from reconstruction.calibration.file import (
    Calibration,
    calibration_from_dict,
    load_calibration,
    save_calibration,
)
from reconstruction.calibration.hand_eye import (
    HAND_EYE_METHODS,
    HandEyeMethodError,
    check_motions,
    solve_hand_eye,
)
from reconstruction.calibration.observations import PoseObservation, board_pose
from reconstruction.calibration.pose_files import (
    POSE_PRESETS,
    PoseFormat,
    pose_format,
    pose_from_numbers,
    read_pose_file,
    read_pose_list,
)
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, pose_difference, transform_points
from reconstruction.stereo.camera_model import PinholeCamera, default_stereo_camera, project_points
from tests.board_views import warped_board

TRANSLATION_TOL_M = 1e-6  # noise-free synthetic data: solvers are exact to numerical precision
ROTATION_TOL_RAD = 1e-6


def _X(rotvec, t):
    return make_pose(Rotation.from_rotvec(rotvec).as_matrix(), t)


# ---------------------------------------------------------------------------- boards
@pytest.mark.parametrize(
    "spec, median_px",
    [
        # findChessboardCornersSB (accuracy mode) is the most precise of the three detectors;
        # ChArUco corners come from cornerSubPix, biased by ~0.1-0.2 px on sharp warped edges.
        (BoardSpec("chessboard", 10, 7, 0.02), 0.05),
        (BoardSpec("charuco", 9, 7, 0.02, 0.015), 0.25),
        (BoardSpec("circles_asymmetric", 4, 11, 0.02, circle_diameter_m=0.008), 0.1),
    ],
    ids=["chessboard", "charuco", "circles"],
)
def test_detection_on_the_printed_pattern_matches_the_board_geometry(spec, median_px):
    """Detect each kind on its own pattern image, warped by a homography: the detected pixels
    are the board points mapped through the same homography."""
    warped, corners = warped_board(spec)
    detection = detect_board(spec, warped)
    assert detection is not None
    err = np.linalg.norm(detection.pixels - corners[detection.ids], axis=1)
    assert len(detection) >= 0.8 * spec.point_count
    assert np.median(err) < median_px


def test_chessboard_orientation_is_fixed_even_upside_down():
    spec = BoardSpec("chessboard", 10, 7, 0.02)
    pattern = board_image(spec, px_per_spacing=40)
    upright = detect_board(spec, pattern.image)
    flipped = detect_board(spec, cv2.rotate(pattern.image, cv2.ROTATE_180))
    h, w = pattern.image.shape
    # Corner k of the rotated image is at (w - u, h - v) of the upright one (edge coordinates).
    mapped = np.array([w - 1, h - 1]) - flipped.pixels
    assert np.abs(mapped - upright.pixels).max() < 0.2


def test_board_validation():
    with pytest.raises(ScannerError, match="not one of"):
        BoardSpec("dots", 5, 5, 0.02)
    with pytest.raises(ScannerError, match="marker_m"):
        BoardSpec("charuco", 5, 5, 0.02, 0.03)
    with pytest.raises(ScannerError, match="spacing"):
        BoardSpec("chessboard", 5, 4, -1.0)


def test_projection_matches_opencv():
    cam = default_stereo_camera().left
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-0.2, 0.2, (50, 2)), rng.uniform(0.3, 0.8, 50)]
    expected, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, cam.distortion)
    assert np.abs(project_points(cam, p) - expected.reshape(-1, 2)).max() < 1e-9


# ---------------------------------------------------------------------------- hand-eye
def _synthetic_observations(
    X_FC, X_WB, camera, board, n=12, seed=0, noise_px=0.0, axes=None
) -> list[PoseObservation]:
    """Flange poses looking at the board from varied directions; exact board detections."""
    rng = np.random.default_rng(seed)
    p_B = board.object_points()
    centre = transform_points(X_WB, np.array([[0.1, 0.07, 0.0]]))[0]
    out = []
    for k in range(n):
        axis = rng.normal(size=3) if axes is None else np.asarray(axes, float)
        axis /= np.linalg.norm(axis)
        tilt = _X(axis * rng.uniform(0.2, 0.5), np.zeros(3))
        # Camera 0.4 m above the board centre looking down its normal, then tilted about it.
        X_WC0 = make_pose(X_WB[:3, :3], centre - X_WB[:3, 2] * 0.4)
        X_WC = make_pose(np.eye(3), centre) @ tilt @ make_pose(np.eye(3), -centre) @ X_WC0
        X_WF = X_WC @ invert(X_FC)
        p_C = transform_points(invert(X_WC) @ X_WB, p_B)
        pixels = project_points(camera, p_C) + rng.normal(0, noise_px, (len(p_B), 2))
        from reconstruction.calibration.boards import Detection

        out.append(PoseObservation(f"pose{k}", X_WF, Detection(np.arange(len(p_B)), pixels)))
    return out


BOARD = BoardSpec("chessboard", 10, 7, 0.02)
X_FC_TRUE = _X([0.02, -0.01, 0.03], [-0.061, 0.002, 0.082])
X_WB_TRUE = _X([math.pi - 0.3, 0.1, 0.05], [0.45, -0.05, 0.1])


def test_every_method_and_the_refinement_recover_exact_data():
    cam = default_stereo_camera().left
    obs = _synthetic_observations(X_FC_TRUE, X_WB_TRUE, cam, BOARD)
    X_CB = [board_pose(BOARD, o.left, cam) for o in obs]
    for method in HAND_EYE_METHODS:
        try:
            X_FC = solve_hand_eye([o.X_WF for o in obs], X_CB, method)
        except HandEyeMethodError:
            # Andreff's linear system is singular on noise-free data; it is reported, not fatal.
            assert method == "andreff"
            continue
        dt, dr = pose_difference(X_FC, X_FC_TRUE)
        assert dt < 1e-5 and dr < 1e-5, method  # closed forms: exact up to PnP precision
    result = calibrate_hand_eye(BOARD, obs, cam)
    dt, dr = pose_difference(result.X_FC, X_FC_TRUE)
    assert dt < TRANSLATION_TOL_M and dr < ROTATION_TOL_RAD
    assert result.outliers == [] and result.rms_px < 1e-6


def test_a_bad_robot_pose_is_rejected_and_the_rest_stays_accurate():
    cam = default_stereo_camera().left
    obs = _synthetic_observations(X_FC_TRUE, X_WB_TRUE, cam, BOARD, noise_px=0.1)
    bad = obs[4]
    # The robot reported a pose 5 mm and 1 degree away from where it was.
    obs[4] = PoseObservation(
        bad.name, bad.X_WF @ _X([0, math.radians(1), 0], [0.005, 0, 0]), bad.left
    )
    result = calibrate_hand_eye(BOARD, obs, cam)
    assert result.outliers == ["pose4"]
    dt, dr = pose_difference(result.X_FC, X_FC_TRUE)
    assert dt < 0.3e-3 and dr < math.radians(0.05)  # the targets


def test_degenerate_motions_are_refused_with_the_reason():
    cam = default_stereo_camera().left
    obs = _synthetic_observations(X_FC_TRUE, X_WB_TRUE, cam, BOARD, axes=[0, 0, 1])
    with pytest.raises(ScannerError, match="about one axis"):
        calibrate_hand_eye(BOARD, obs, cam)
    translations = [make_pose(np.eye(3), [0.01 * k, 0, 0]) for k in range(6)]
    with pytest.raises(ScannerError, match="differ by at most 0.00 deg"):
        check_motions(translations, CalibrationSettings())


def test_too_few_poses_says_how_many_more():
    cam = default_stereo_camera().left
    obs = _synthetic_observations(X_FC_TRUE, X_WB_TRUE, cam, BOARD, n=6)
    obs = obs[:3] + [PoseObservation(o.name, o.X_WF, None) for o in obs[3:]]
    with pytest.raises(ScannerError) as e:
        calibrate_hand_eye(BOARD, obs, cam)
    message = str(e.value)
    assert "only 3 of 6 poses are usable" in message
    assert "record 2 more pose(s)" in message
    assert "pose3, pose4, pose5" in message


def test_solver_settings_are_validated():
    with pytest.raises(ScannerError, match="robust_loss 'l3'"):
        CalibrationSettings(robust_loss="l3")
    with pytest.raises(ScannerError, match="at least 3"):
        CalibrationSettings(min_poses=2)
    with pytest.raises(ScannerError, match="valid: tsai, park"):
        solve_hand_eye([np.eye(4)] * 3, [np.eye(4)] * 3, "magic")


# ---------------------------------------------------------------------------- pose files
def test_pose_layouts_agree():
    R = Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    X = make_pose(R.as_matrix(), [0.1, 0.2, 0.3])
    cases = [
        (PoseFormat("matrix", length_unit="m"), X.ravel()),
        (PoseFormat("matrix", length_unit="mm"), np.c_[X[:3, :3], X[:3, 3] * 1000].ravel()),
        (PoseFormat("xyz_euler", "xyz", "m", "deg"), [0.1, 0.2, 0.3, 10, -20, 30]),
        (PoseFormat("euler_xyz", "xyz", "mm", "deg"), [10, -20, 30, 100, 200, 300]),
        (PoseFormat("xyz_euler", "ZYX", "m", "deg"), [0.1, 0.2, 0.3, 30, -20, 10]),
        (PoseFormat("xyz_quat", length_unit="m"), np.r_[0.1, 0.2, 0.3, R.as_quat()]),
        (PoseFormat("xyz_wxyz", length_unit="m"), np.r_[0.1, 0.2, 0.3, np.roll(R.as_quat(), 1)]),
        (PoseFormat("xyz_rotvec", "xyz", "m", "rad"), np.r_[0.1, 0.2, 0.3, R.as_rotvec()]),
    ]
    for fmt, values in cases:
        assert np.allclose(pose_from_numbers(np.array(values, float), fmt, "t"), X, atol=1e-9)
    inverse_fmt = PoseFormat("matrix", inverse=True)
    assert np.allclose(pose_from_numbers(invert(X).ravel(), inverse_fmt, "t"), X)


def test_pose_file_errors_name_the_file_line_and_expectation(tmp_path):
    six = tmp_path / "pose.txt"
    six.write_text("1 2 3\n4 5\n")
    with pytest.raises(ScannerError, match=r"pose.txt: found 5 numbers, .*'xyz_euler' needs 6"):
        read_pose_file(six, PoseFormat("xyz_euler"))
    listing = tmp_path / "poses.txt"
    listing.write_text("# x y z rx ry rz\n0 0 0 0 0 0\n1 2 3 4 5\n")
    with pytest.raises(ScannerError, match=r"poses.txt line 3: 5 columns"):
        read_pose_list(listing, PoseFormat("xyz_euler"))
    with pytest.raises(ScannerError, match="unknown pose convention 'kukka'; valid: open3dv"):
        pose_format("kukka")
    with pytest.raises(ScannerError, match="unknown Euler convention 'xxy'"):
        PoseFormat("xyz_euler", "xxy")
    with pytest.raises(ScannerError, match="unknown pose layout"):
        PoseFormat("quaternion")
    with pytest.raises(ScannerError, match="unknown length unit 'cm'"):
        pose_format("kuka", length_unit="cm")
    bad_matrix = tmp_path / "matrix.txt"
    bad_matrix.write_text(" ".join(["1"] * 16))
    with pytest.raises(ScannerError, match="not a rotation|last matrix row"):
        read_pose_file(bad_matrix, POSE_PRESETS["matrix_m"])


# One pose list (x y z in mm, rotation vector in rad) as people and spreadsheets write it.
POSE_ROWS = [[100.0, -20.5, 300.0, 0.1, -0.2, 0.3], [110.0, -21.0, 290.0, 0.0, 0.0, 1.5]]
POSE_LIST_TEXTS = {
    "spaces": "100 -20.5 300 0.1 -0.2 0.3\n110 -21 290 0 0 1.5\n",
    "trailing blank lines": "100 -20.5 300 0.1 -0.2 0.3\n110 -21 290 0 0 1.5\n\n  \n\t\n",
    "comments": (
        "# poses of the calibration run\n"
        "100 -20.5 300 0.1 -0.2 0.3  # first view\n"
        "   # robot paused here\n"
        "110 -21 290 0 0 1.5#second\n"
    ),
    "commas": "100,-20.5,300,0.1,-0.2,0.3\n110, -21, 290, 0, 0, 1.5\n",
    "semicolons": "100;-20.5;300;0.1;-0.2;0.3\n110 ; -21 ; 290 ; 0 ; 0 ; 1.5\n",
    "tabs": "100\t-20.5\t300\t0.1\t-0.2\t0.3\n110\t-21\t290\t0\t0\t1.5\n",
    "csv header": "x,y,z,rx,ry,rz\n100,-20.5,300,0.1,-0.2,0.3\n110,-21,290,0,0,1.5\n",
    "header with units after a comment": (
        "# exported by the robot controller\n"
        "X [mm]; Y [mm]; Z [mm]; Rx [rad]; Ry [rad]; Rz [rad]\n"
        "100;-20.5;300;0.1;-0.2;0.3\n110;-21;290;0;0;1.5\n"
    ),
    "quoted spreadsheet cells": '"x","y","z","rx","ry","rz"\n'
    '"100","-20.5","300","0.1","-0.2","0.3"\n"110","-21","290","0","0","1.5"\n',
    "windows line endings": "100 -20.5 300 0.1 -0.2 0.3\r\n110 -21 290 0 0 1.5\r\n\r\n",
}


@pytest.mark.parametrize("text", POSE_LIST_TEXTS.values(), ids=POSE_LIST_TEXTS.keys())
def test_pose_lists_as_people_write_them(tmp_path, text):
    fmt = pose_format("ur", length_unit="mm")
    path = tmp_path / "poses.csv"
    path.write_bytes(text.encode())
    expected = [pose_from_numbers(np.array(row), fmt, "t") for row in POSE_ROWS]
    poses = read_pose_list(path, fmt)
    assert len(poses) == len(expected)
    for X, X_expected in zip(poses, expected):
        np.testing.assert_allclose(X, X_expected, atol=1e-12)


def test_a_spreadsheet_byte_order_mark_and_a_header_in_a_single_pose_file(tmp_path):
    fmt = pose_format("ur", length_unit="mm")
    path = tmp_path / "pose0.txt"
    path.write_bytes("\ufeffx;y;z;rx;ry;rz\r\n100;-20.5;300;0.1;-0.2;0.3\r\n".encode())
    expected = pose_from_numbers(np.array(POSE_ROWS[0]), fmt, "t")
    np.testing.assert_allclose(read_pose_file(path, fmt), expected, atol=1e-12)


@pytest.mark.parametrize(
    "data, message",
    [
        # Line 4 is the bad one: the header, a comment and a blank line come first.
        (b"x,y,z,rx,ry,rz\n# run 1\n\n0.1,0.2,0.3,0,0,O.1\n", " line 4: not a list of numbers"),
        # Only the first line can be a header: text further down is an error, not skipped.
        (b"x,y,z,rx,ry,rz\n0.1,0.2,0.3,0,0,0.1\nend of list\n", " line 3: not a list of numbers"),
        # A first line mixing numbers and text is a bad row, not a header.
        (b"pose 1: 0.1 0.2 0.3 0 0 0.1\n", " line 1: not a list of numbers"),
        (b"0.1;0.2;0.3;0;0;0.1\r\n0.1;0.2;0.3;0;0\r\n", " line 2: 5 columns"),
        # UTF-16, as some editors save "Unicode".
        (b"\xff\xfe0\x00.\x001\x00", ": not UTF-8 text"),
    ],
)
def test_bad_pose_rows_name_the_file_and_line_after_headers_and_comments(tmp_path, data, message):
    path = tmp_path / "poses.csv"
    path.write_bytes(data)
    with pytest.raises(ScannerError, match="poses.csv" + message):
        read_pose_list(path, pose_format("ur"))


def test_a_pose_count_that_does_not_match_the_images_names_both(tmp_path):
    from scanner.calibrate.offline import OfflineOptions, calibrate_directory

    folder = tmp_path / "data"
    folder.mkdir()
    for k in range(2):
        cv2.imwrite(str(folder / f"view{k}.png"), np.full((48, 64), 255, np.uint8))
    poses = tmp_path / "poses.csv"
    poses.write_text("x,y,z,rx,ry,rz\n" + "0.1,0.2,0.3,0,0,0.1\n" * 3 + "\n\n")
    options = OfflineOptions(BoardSpec("chessboard", 10, 7, 0.02), pose_format("ur"), poses)
    with pytest.raises(ScannerError, match=r"poses.csv: 3 poses for 2 images"):
        calibrate_directory(folder, options, out_dir=tmp_path / "out")


def test_open3dv_convention_matches_its_readme():
    # README: R_base_gripper = Rotation.from_euler('xyz', [Rx, Ry, Rz], degrees=True).
    X = pose_from_numbers(
        np.array([-176.5919, 9.8196, 2.0734, 905.634, -110.794, 337.887]),
        POSE_PRESETS["open3dv"],
        "pos0",
    )
    R = Rotation.from_euler("xyz", [-176.5919, 9.8196, 2.0734], degrees=True).as_matrix()
    assert np.allclose(X[:3, :3], R) and np.allclose(X[:3, 3], [0.905634, -0.110794, 0.337887])


# ---------------------------------------------------------------------------- calibration file
def test_calibration_file_round_trip(tmp_path):
    stereo = default_stereo_camera()
    cal = Calibration(
        X_FC_TRUE,
        stereo,
        stereo.left,
        "test",
        "",
        X_WB_TRUE,
        {"kind": "x"},
        {"reprojection_rms_px": np.float64(0.1), "used": np.array([1, 2])},
    )
    path = save_calibration(cal, tmp_path / "calibration.yaml")
    back = load_calibration(path)
    assert np.allclose(back.X_FC, X_FC_TRUE) and back.stereo is not None
    assert np.allclose(back.stereo.R, stereo.R) and back.quality["used"] == [1, 2]
    mono = Calibration(
        X_FC_TRUE,
        None,
        PinholeCamera(np.eye(3) * 100 + np.diag([0, 0, -99]), np.zeros(5), 640, 480),
    )
    back = load_calibration(save_calibration(mono, tmp_path / "mono.yaml"))
    assert back.stereo is None and back.camera.width == 640


def test_calibration_file_errors(tmp_path):
    with pytest.raises(ScannerError, match="schema"):
        calibration_from_dict({"schema": "other"}, "f.yaml")
    with pytest.raises(ScannerError, match="missing key 'X_FC'"):
        calibration_from_dict({"schema": "scanner.calibration/1"}, "f.yaml")
    d = {"schema": "scanner.calibration/1", "X_FC": np.eye(4).tolist(), "camera": {"K": 1}}
    with pytest.raises(ScannerError, match="f.yaml:camera"):
        calibration_from_dict(d, "f.yaml")
    d = {
        "schema": "scanner.calibration/1",
        "X_FC": (2 * np.eye(4)).tolist(),
        "stereo_camera": None,
        "camera": {"image_size": [4, 4], "K": np.eye(3).tolist(), "distortion": [0] * 5},
    }
    with pytest.raises(ScannerError, match="X_FC: not a rigid transform"):
        calibration_from_dict(d, "f.yaml")
    with pytest.raises(ScannerError, match="cannot read"):
        load_calibration(tmp_path / "none.yaml")
