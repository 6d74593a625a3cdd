"""Calibrations in OpenCV's and ROS's files: exact round trips, OpenCV's and ROS's conventions
checked with their own tools (cv2.FileStorage, cv2.stereoRectify, scipy's quaternions), and bad
files as one-line errors naming the file and the key."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from reconstruction.calibration import exchange
from reconstruction.calibration.file import Calibration, load_calibration, save_calibration
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, rotation_about, transform_points
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera, default_stereo_camera
from scanner.commands.main import main

# Round trips through rectification matrices (ROS) lose a few ulps of the rotation; 1e-12 rad
# and 1e-12 m are far below anything a calibration resolves (~1e-5 rad, ~1e-5 m).
FLOAT_TOL = 1e-12

# The right camera in the left optical frame: 0.12 m to the right, a little off the axis, turned
# 1.7 deg about a skew axis (a real rig's numbers, not a textbook one's).
X_CR = make_pose(rotation_about([0.2, 1.0, 0.1], 0.03), [0.1203, 0.0011, -0.0023])
# The left optical frame in the flange, turned about every axis.
X_FC = make_pose(rotation_about([0.3, -0.5, 1.0], 2.1), [-0.061, 0.004, 0.0815])


@pytest.fixture(scope="module")
def stereo() -> StereoCamera:
    left = PinholeCamera(
        np.array([[1321.3, 0.0, 641.7], [0.0, 1318.9, 478.2], [0.0, 0.0, 1.0]]),
        np.array([-0.41, 0.18, 1e-3, -2e-4, 0.01]),
        1280,
        960,
    )
    right = PinholeCamera(
        np.array([[1317.1, 0.0, 637.2], [0.0, 1316.0, 482.9], [0.0, 0.0, 1.0]]),
        np.array([-0.43, 0.2, -5e-4, 3e-4, -0.02]),
        1280,
        960,
    )
    X_RC = invert(X_CR)
    return StereoCamera(left, right, X_RC[:3, :3], X_RC[:3, 3])


def _assert_same_cameras(a: StereoCamera, b: StereoCamera) -> None:
    assert a.image_size == b.image_size
    for ca, cb in ((a.left, b.left), (a.right, b.right)):
        assert np.array_equal(ca.K, cb.K) and np.array_equal(ca.distortion, cb.distortion)


# ------------------------------------------------------------------------------------ OpenCV
def test_opencv_round_trip_is_exact(stereo, tmp_path):
    exchange.write_opencv_stereo(stereo, tmp_path)
    back = exchange.read_opencv_stereo(tmp_path)
    _assert_same_cameras(stereo, back)
    # FileStorage writes 17 significant digits: every double reads back bit for bit.
    assert np.array_equal(back.R, stereo.R) and np.array_equal(back.T, stereo.T)


def test_opencv_files_follow_opencvs_conventions(stereo, tmp_path):
    exchange.write_opencv_stereo(stereo, tmp_path)
    fs_i = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    fs_e = cv2.FileStorage(str(tmp_path / "extrinsics.yml"), cv2.FILE_STORAGE_READ)
    M1, D1 = fs_i.getNode("M1").mat(), fs_i.getNode("D1").mat()
    M2, D2 = fs_i.getNode("M2").mat(), fs_i.getNode("D2").mat()
    R, T = fs_e.getNode("R").mat(), fs_e.getNode("T").mat()
    assert D1.shape == (1, 5) and T.shape == (3, 1)
    assert np.array_equal(M1, stereo.left.K) and np.array_equal(D2.ravel(), stereo.right.distortion)
    size = (int(fs_i.getNode("image_width").real()), int(fs_i.getNode("image_height").real()))
    assert size == (1280, 960) and fs_e.getNode("length_unit").string() == "m"

    # x_right = R x_left + T: (R, T) is the inverse of X_CR, the right camera in the left frame.
    X_RC = invert(X_CR)
    assert np.allclose(R, X_RC[:3, :3], rtol=0, atol=FLOAT_TOL)
    assert np.allclose(T.ravel(), X_RC[:3, 3], rtol=0, atol=FLOAT_TOL)
    assert T[0, 0] < 0  # the right camera sits at +x of the left one: OpenCV's T is (-b, ., .)

    # R1 ... Q are what cv2.stereoRectify gives for these files, as stereo_calib computes them.
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        M1, D1, M2, D2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    for key, expected in (("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2), ("Q", Q)):
        assert np.array_equal(fs_e.getNode(key).mat(), expected), key

    # And they measure: a point 0.6 m in front of the left camera, seen by both rectified
    # cameras, comes back from its disparity through Q (in the rectified left frame).
    p_C = np.array([0.05, -0.03, 0.6])
    p_R = transform_points(invert(X_CR), p_C[None])[0]
    u_left = P1 @ np.append(R1 @ p_C, 1)
    # P2 takes points in the rectified left frame; the right camera's own rectified frame (R2)
    # with P2's intrinsics alone must see the same pixel.
    u_right = P2 @ np.append(R1 @ p_C, 1)
    assert np.allclose(P2[:, :3] @ (R2 @ p_R), u_right, rtol=1e-12, atol=0)
    x, y = u_left[:2] / u_left[2]
    disparity = x - u_right[0] / u_right[2]
    X = Q @ np.array([x, y, disparity, 1.0])
    assert np.allclose(X[:3] / X[3], R1 @ p_C, rtol=0, atol=1e-9)


def _write_filestorage(path, entries) -> None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries:
        fs.write(key, value)
    fs.release()


def test_opencv_stereo_calib_sample_files(stereo, tmp_path):
    """What stereo_calib.cpp writes: no image size, an 8-term D (rational model with k3..k6
    fixed at 0), T in board squares."""
    square_m = 0.025
    _write_filestorage(
        tmp_path / "intrinsics.yml",
        [
            ("M1", stereo.left.K),
            ("D1", np.append(stereo.left.distortion, [0, 0, 0]).reshape(1, 8)),
            ("M2", stereo.right.K),
            ("D2", np.append(stereo.right.distortion, [0, 0, 0]).reshape(1, 8)),
        ],
    )
    _write_filestorage(
        tmp_path / "extrinsics.yml", [("R", stereo.R), ("T", stereo.T.reshape(3, 1) / square_m)]
    )
    with pytest.raises(ScannerError, match=r"intrinsics\.yml: no image_width.*image size"):
        exchange.read_opencv_stereo(tmp_path)
    back = exchange.read_opencv_stereo(tmp_path, (1280, 960), square_m)
    _assert_same_cameras(stereo, back)
    assert np.allclose(back.T, stereo.T, rtol=1e-15, atol=0)
    # A rational term the model here cannot hold is refused, not dropped.
    _write_filestorage(
        tmp_path / "intrinsics.yml",
        [
            ("M1", stereo.left.K),
            ("D1", np.append(stereo.left.distortion, [0, 0, 0.3]).reshape(1, 8)),
        ],
    )
    with pytest.raises(ScannerError, match=r"intrinsics\.yml: D1: coefficients beyond"):
        exchange.read_opencv_stereo(tmp_path, (1280, 960))


def test_opencv_units_and_sizes_must_agree(stereo, tmp_path):
    exchange.write_opencv_stereo(stereo, tmp_path)
    with pytest.raises(ScannerError, match=r"extrinsics\.yml: length_unit says 'm'"):
        exchange.read_opencv_stereo(tmp_path, length_unit_m=0.001)
    with pytest.raises(ScannerError, match=r"intrinsics\.yml: .* say 1280x960.* 640x480"):
        exchange.read_opencv_stereo(tmp_path, image_size=(640, 480))
    assert exchange.parse_length_unit("mm") == 0.001
    assert exchange.parse_length_unit("0.025") == 0.025
    for bad in ("", "km", "0", "-1", "nan", "inf"):
        with pytest.raises(ScannerError, match="length unit"):
            exchange.parse_length_unit(bad)


def _replace_line(path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


STEREO_FORMATS = {
    "opencv": (exchange.write_opencv_stereo, exchange.read_opencv_stereo),
    "ros": (exchange.write_ros_camera_info, exchange.read_ros_camera_info),
}
# Damaged files by format and file: (text in the written file, its replacement, the error naming
# the file and key).
DAMAGED_FILES = {
    ("opencv", "intrinsics.yml"): [
        ("M1:", "X1:", r"intrinsics\.yml: missing key 'M1'"),
        ("rows: 3\n   cols: 3", "rows: 1\n   cols: 9", r"M1 is 1x9, expected 3x3"),
        ("D1:", "D1: 5\nX:", r"intrinsics\.yml: D1 is not an OpenCV matrix"),
        ("image_width: 1280", "image_width: -3", r"image_width must be"),
    ],
    ("opencv", "extrinsics.yml"): [
        ("T:", "U:", r"extrinsics\.yml: missing key 'T'"),
        ("rows: 3\n   cols: 1", "rows: 2\n   cols: 1", r"T is not an Op.*nelems"),
        ("length_unit: m", "length_unit: parsec", r"length_unit: length unit"),
        ("R: !!opencv-matrix", "R: [1, 2", r"extrinsics\.yml: not an OpenCV"),
    ],
    ("ros", "left.yaml"): [
        ("camera_matrix:\n  rows: 3", "camera_matrix:\n  rows: 2", r"camera_matrix is 2x3"),
        ("distortion_model: plumb_bob", "distortion_model: equidistant", r"equidistant"),
        ("image_height: 960", "image_height: tall", r"left\.yaml: image_height must be"),
        ("rows: 1\n  cols: 5", "rows: 1\n  cols: 4", r"distortion_coefficients has 5"),
    ],
    ("ros", "right.yaml"): [
        ("projection_matrix:", "projection:", r"right\.yaml: missing key 'projection_"),
        ("image_width: 1280", "image_width: 640", r"right\.yaml: image_width/image_h"),
        ("camera_name: right", "camera_name: [", r"right\.yaml: ROS camera_info is not"),
    ],
}


@pytest.mark.parametrize(
    "fmt, name, old, new, message",
    [(fmt, name, *case) for (fmt, name), cases in DAMAGED_FILES.items() for case in cases],
)
def test_bad_files_name_file_and_key(stereo, tmp_path, fmt, name, old, new, message):
    write, read = STEREO_FORMATS[fmt]
    write(stereo, tmp_path)
    _replace_line(tmp_path / name, old, new)
    with pytest.raises(ScannerError, match=message):
        read(tmp_path)


def test_opencv_unreadable_files(stereo, tmp_path):
    with pytest.raises(ScannerError, match="not a folder"):
        exchange.read_opencv_stereo(tmp_path / "missing")
    with pytest.raises(ScannerError, match=r"intrinsics\.yml: cannot read"):
        exchange.read_opencv_stereo(tmp_path)
    exchange.write_opencv_stereo(stereo, tmp_path)
    (tmp_path / "extrinsics.yml").write_bytes(bytes(range(256)))
    with pytest.raises(ScannerError, match=r"extrinsics\.yml: not a text file"):
        exchange.read_opencv_stereo(tmp_path)
    if os.geteuid() != 0:  # root reads every file
        exchange.write_opencv_stereo(stereo, tmp_path)
        (tmp_path / "intrinsics.yml").chmod(0)
        with pytest.raises(ScannerError, match=r"intrinsics\.yml: cannot read .*ermission"):
            exchange.read_opencv_stereo(tmp_path)


# --------------------------------------------------------------------------------------- ROS
def test_ros_round_trip(stereo, tmp_path):
    exchange.write_ros_camera_info(stereo, tmp_path)
    back = exchange.read_ros_camera_info(tmp_path)
    _assert_same_cameras(stereo, back)
    assert np.allclose(back.R, stereo.R, rtol=0, atol=FLOAT_TOL)
    assert np.allclose(back.T, stereo.T, rtol=0, atol=FLOAT_TOL)
    assert np.allclose(back.X_CR, X_CR, rtol=0, atol=FLOAT_TOL)


def test_ros_files_have_camera_info_keys_and_shapes(stereo, tmp_path):
    exchange.write_ros_camera_info(stereo, tmp_path)
    shapes = {
        "camera_matrix": (3, 3),
        "distortion_coefficients": (1, 5),
        "rectification_matrix": (3, 3),
        "projection_matrix": (3, 4),
    }
    infos = {}
    for side in ("left", "right"):
        info = yaml.safe_load((tmp_path / f"{side}.yaml").read_text())
        assert list(info) == [
            "image_width",
            "image_height",
            "camera_name",
            "camera_matrix",
            "distortion_model",
            "distortion_coefficients",
            "rectification_matrix",
            "projection_matrix",
        ]
        assert (info["image_width"], info["image_height"]) == (1280, 960)
        assert info["camera_name"] == side and info["distortion_model"] == "plumb_bob"
        for key, (rows, cols) in shapes.items():
            assert (info[key]["rows"], info[key]["cols"]) == (rows, cols)
            assert len(info[key]["data"]) == rows * cols
        infos[side] = {k: np.reshape(info[k]["data"], shapes[k]) for k in shapes}
    assert np.array_equal(infos["left"]["camera_matrix"], stereo.left.K)
    P1, P2 = infos["left"]["projection_matrix"], infos["right"]["projection_matrix"]
    # ROS: the left camera's Tx is 0, the right one's is -fx' * baseline (metres).
    assert P1[0, 3] == 0 and P1[1, 3] == 0
    assert np.isclose(P2[0, 3], -P2[0, 0] * stereo.baseline_m, rtol=1e-12, atol=0)


def test_ros_pair_without_baseline_is_refused(stereo, tmp_path):
    """Two monocular camera_info files (Tx = 0) are not a stereo pair."""
    exchange.write_ros_camera_info(stereo, tmp_path)
    info = yaml.safe_load((tmp_path / "right.yaml").read_text())
    info["projection_matrix"]["data"][3] = 0.0
    (tmp_path / "right.yaml").write_text(yaml.safe_dump(info))
    with pytest.raises(ScannerError, match=r"right\.yaml: projection_matrix Tx is 0.0"):
        exchange.read_ros_camera_info(tmp_path)
    (tmp_path / "left.yaml").unlink()
    with pytest.raises(ScannerError, match=r"left\.yaml: cannot read"):
        exchange.read_ros_camera_info(tmp_path)


# -------------------------------------------------------------------------- static transform
@pytest.mark.parametrize("angle", [2.1, 3.0, -0.4])  # 3.0 rad about this axis gives qw < 0 ...
def test_static_transform_reproduces_X_FC(angle, tmp_path):
    X = make_pose(rotation_about([0.3, -0.5, 1.0], angle), [-0.061, 0.004, 0.0815])
    tf = exchange.static_transform(X, "tool0", "camera_optical_frame")
    assert tf.quaternion_xyzw[3] >= 0  # ... unless flipped: one rotation, one set of numbers
    R = Rotation.from_quat(tf.quaternion_xyzw).as_matrix()  # scipy's order is (x, y, z, w) too
    assert np.allclose(R, X[:3, :3], rtol=0, atol=FLOAT_TOL)
    assert np.allclose(tf.translation_m, X[:3, 3], rtol=0, atol=0)
    assert np.allclose(tf.X_PC, X, rtol=0, atol=FLOAT_TOL)
    (path,) = exchange.write_static_transform(tf, tmp_path)
    d = yaml.safe_load(path.read_text())
    assert (d["parent_frame"], d["child_frame"]) == ("tool0", "camera_optical_frame")
    assert list(d["transformation"]) == ["x", "y", "z", "qx", "qy", "qz", "qw"]
    assert np.allclose(exchange.read_hand_eye(path), X, rtol=0, atol=FLOAT_TOL)

    numbers = [*tf.translation_m, *tf.quaternion_xyzw]
    ros1 = d["ros1_command"].split()
    assert ros1[:3] == ["rosrun", "tf2_ros", "static_transform_publisher"]
    assert [float(v) for v in ros1[3:10]] == numbers and ros1[10:] == ["tool0", d["child_frame"]]
    ros2 = d["ros2_command"].split()
    assert ros2[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    flags = dict(zip(ros2[4::2], ros2[5::2]))
    assert [float(flags[f]) for f in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")] == (
        numbers
    )
    assert flags["--frame-id"] == "tool0" and flags["--child-frame-id"] == "camera_optical_frame"
    assert f'args="{" ".join(ros1[3:])}"' in d["ros1_launch"]


def test_hand_eye_from_easy_handeye_files(tmp_path):
    q = Rotation.from_matrix(X_FC[:3, :3]).as_quat().tolist()
    t = X_FC[:3, 3].tolist()
    one = tmp_path / "easy_handeye.yaml"
    one.write_text(
        yaml.safe_dump(
            {
                "parameters": {"eye_on_hand": True, "robot_effector_frame": "tool0"},
                "transformation": dict(zip(["x", "y", "z", "qx", "qy", "qz", "qw"], [*t, *q])),
            }
        )
    )
    two = tmp_path / "easy_handeye2.calib"
    two.write_text(
        yaml.safe_dump(
            {
                "parameters": {"calibration_type": "eye_in_hand"},
                "transform": {
                    "translation": dict(zip("xyz", t)),
                    "rotation": dict(zip("xyzw", q)),
                },
            }
        )
    )
    for path in (one, two):
        assert np.allclose(exchange.read_hand_eye(path), X_FC, rtol=0, atol=FLOAT_TOL)
    base = tmp_path / "on_base.yaml"
    base.write_text(yaml.safe_dump({"parameters": {"eye_on_hand": False}, "transformation": {}}))
    with pytest.raises(ScannerError, match="on_base.yaml: an eye-on-base"):
        exchange.read_hand_eye(base)


@pytest.mark.parametrize(
    "content, message",
    [
        ({"transformation": {"x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0}}, "'transforma"),
        ({"transformation": {"x": 0, "y": 0, "z": "a", "qx": 0, "qy": 0, "qz": 0, "qw": 1}}, "z m"),
        ({"transformation": {"x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 2}}, "len"),
        ({"transform": {"translation": {"x": 0}}}, r"missing key 'transform\.translation\.y'"),
        ({"frames": 1}, "missing key 'transformation'"),
        ([1, 2], "not a hand-eye transform file"),
    ],
)
def test_hand_eye_bad_files_name_file_and_key(tmp_path, content, message):
    path = tmp_path / "tf.yaml"
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(ScannerError, match=f"tf.yaml: .*{message}"):
        exchange.read_hand_eye(path)


def test_frame_names_are_checked():
    for bad in ("", "two words", "/tool0", "9lives", "a;b", "tool0/"):
        with pytest.raises(ScannerError, match="not a ROS frame name"):
            exchange.static_transform(np.eye(4), bad, "camera_optical_frame")
    with pytest.raises(ScannerError, match="both 'tool0'"):
        exchange.static_transform(np.eye(4), "tool0", "tool0")
    exchange.static_transform(np.eye(4), "rx60/tool0", "bumblebee/left_optical")


# ------------------------------------------------------------------------------ command line
@pytest.fixture
def calibration_file(stereo, tmp_path):
    return save_calibration(
        Calibration(X_FC, stereo, stereo.left, source="test"), tmp_path / "calibration.yaml"
    )


def test_export_and_import_through_the_command_line(stereo, calibration_file, tmp_path, capsys):
    out = tmp_path / "exported"
    for fmt in ("opencv", "ros", "ros-tf"):
        assert main(["export", str(calibration_file), "--format", fmt, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "rosrun tf2_ros static_transform_publisher" in printed and "--child-frame-id" in printed
    names = ["extrinsics.yml", "hand_eye_tf.yaml", "intrinsics.yml", "left.yaml", "right.yaml"]
    assert sorted(p.name for p in out.iterdir()) == names  # no staging folder left

    for fmt in ("opencv", "ros"):
        target = tmp_path / f"from-{fmt}.yaml"
        argv = ["import-calibration", "--format", fmt, str(out), "--out", str(target)]
        assert main([*argv, "--hand-eye", str(out / "hand_eye_tf.yaml")]) == 0
        back = load_calibration(target)
        _assert_same_cameras(stereo, back.stereo)
        assert np.allclose(back.stereo.X_CR, X_CR, rtol=0, atol=FLOAT_TOL)
        assert np.allclose(back.X_FC, X_FC, rtol=0, atol=FLOAT_TOL)
        # The file is there now: not replaced without --force.
        before = target.read_text()
        assert main([*argv, "--hand-eye", str(out / "hand_eye_tf.yaml")]) == 2
        assert target.read_text() == before
        assert "--force" in capsys.readouterr().err
        assert main([*argv, "--force"]) == 0  # nominal X_FC without --hand-eye, said so
        assert "nominal" in capsys.readouterr().out


def test_export_refuses_to_replace_files(calibration_file, tmp_path, capsys):
    out = tmp_path / "exported"
    argv = ["export", str(calibration_file), "--format", "ros-tf", "--out", str(out)]
    assert main([*argv, "--child-frame", "left_optical"]) == 0
    before = (out / "hand_eye_tf.yaml").read_text()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hand_eye_tf.yaml already" in err[0] and "--force" in err[0]
    assert (out / "hand_eye_tf.yaml").read_text() == before
    assert main([*argv, "--force"]) == 0
    assert "camera_optical_frame" in (out / "hand_eye_tf.yaml").read_text()


def test_export_of_one_camera_writes_no_stereo_files(tmp_path, capsys):
    mono = default_stereo_camera().left
    path = save_calibration(Calibration(X_FC, None, mono), tmp_path / "mono.yaml")
    out = tmp_path / "exported"
    assert main(["export", str(path), "--format", "opencv", "--out", str(out)]) == 2
    assert "holds one camera" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
    assert main(["export", str(path), "--format", "ros-tf", "--out", str(out)]) == 0
