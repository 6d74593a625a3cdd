"""Every option of every subcommand with bad values (wrong types, negative, zero, NaN, infinite,
huge, missing or unusable paths, unknown names): exit 2, one line naming the option or the value,
never a traceback, and no work started (the expensive stages are replaced by a tripwire)."""

from __future__ import annotations

import os
import string

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from reconstruction.calibration import exchange
from reconstruction.calibration.file import Calibration, save_calibration
from scanner.commands.main import build_parser, main
from scanner.configs.scan import ScanConfig
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.manifest import new_manifest


class WorkStartedError(Exception):
    """A bad value got past the checks into real work."""


def _tripwire(*args, **kwargs):
    raise WorkStartedError("a bad value reached the expensive stages")


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    """Valid context for the options that need one, and unusable paths of every kind."""
    root = tmp_path_factory.mktemp("places")
    (root / "file.txt").write_text("not what was asked for")
    (root / "empty").mkdir()
    (root / "list.yaml").write_text("- 1\n- 2\n")
    (root / "broken.yaml").write_text("views: {count: [\n")
    (root / "binary.yaml").write_bytes(bytes(range(256)))
    config = ScanConfig()
    stereo = config.camera.stereo_camera()
    for name in ("scan", "scan2"):
        CaptureStore.create(root / name, new_manifest(config, stereo, np.eye(4), [], {}))
    foreign = root / "foreign"
    foreign.mkdir()
    for k in range(3):
        cv2.imwrite(str(foreign / f"pos{k}.png"), np.full((48, 64), 128, np.uint8))
        (foreign / f"pos{k}.txt").write_text("0 0 0 100 200 300\n")
    save_calibration(Calibration(np.eye(4), stereo, stereo.left), root / "calibration.yaml")
    save_calibration(Calibration(np.eye(4), None, stereo.left), root / "mono.yaml")
    for name, write in (
        ("opencv", exchange.write_opencv_stereo),
        ("ros", exchange.write_ros_camera_info),
    ):
        (root / name).mkdir()
        write(stereo, root / name)
    import open3d as o3d

    o3d.io.write_triangle_mesh(str(root / "model.ply"), o3d.geometry.TriangleMesh.create_box())
    tf = exchange.static_transform(np.eye(4))
    (root / "he.yaml").write_text(exchange.static_transform_text(tf))
    _idr_recording(root / "idr")
    return root


def _idr_recording(folder) -> None:
    """A valid IDR recording: two 32x24 views 100 mm apart (the format's default unit), 1 m
    from the origin (the scale_mat centre), looking along +z."""
    (folder / "images").mkdir(parents=True)
    K = np.array([[30.0, 0, 15.5], [0, 30.0, 11.5], [0, 0, 1]])
    cameras = {}
    for i in range(2):
        cv2.imwrite(str(folder / "images" / f"{i}.png"), np.full((24, 32, 3), 90, np.uint8))
        p_WC = np.array([100.0 * i, 0.0, -1000.0])
        cameras[f"world_mat_{i}"] = np.vstack(
            [K @ np.column_stack([np.eye(3), -p_WC]), [0, 0, 0, 1]]
        )
        cameras[f"scale_mat_{i}"] = np.eye(4)
    np.savez(folder / "cameras_sphere.npz", **cameras)


PATHS = [
    "/nonexistent/x",
    "{root}/file.txt",
    "{root}/empty",
    "{root}/list.yaml",
    "{root}/broken.yaml",
    "{root}/binary.yaml",
    "",
]
OUT_PATHS = ["{root}/file.txt", "/proc/forbidden", "/proc/self/x", "{root}/file.txt/sub"]


def _floats(maximum: float | None) -> st.SearchStrategy[str]:
    bad = [
        st.sampled_from(["nan", "inf", "-inf", "-0", "0", "abc", "", "1e400", "0x1p3", "1,5"]),
        st.floats(max_value=0, allow_nan=False).map(repr),
        st.text(string.ascii_letters, min_size=1, max_size=6),
    ]
    if maximum is not None:
        bad.append(st.floats(min_value=maximum * 1.01, allow_infinity=False).map(repr))
    return st.one_of(*bad)


def _ints(minimum: int, maximum: int) -> st.SearchStrategy[str]:
    return st.one_of(
        st.integers(max_value=minimum - 1).map(str),
        st.integers(min_value=maximum + 1).map(str),
        st.sampled_from(["1.5", "abc", "", "nan", "1e3", "0x10"]),
    )


def _names(valid: list[str]) -> st.SearchStrategy[str]:
    return st.text(min_size=0, max_size=12).filter(lambda s: s not in valid and "\0" not in s)


def _paths(choices: list[str]) -> st.SearchStrategy[str]:
    return st.sampled_from(choices)


BAD_FRAMES = st.one_of(
    st.sampled_from(["two words", "/tool0", "9lives", "a;b", "tool0/", "a//b", "-x", ""]),
    st.text(max_size=12).filter(
        lambda s: not exchange.ROS_FRAME_PATTERN.fullmatch(s) and "\0" not in s
    ),
)
BAD_IMAGE_SIZES = st.sampled_from(
    ["", "640", "640x", "x480", "0x480", "640x0", "-640x480", "abc", "640x480x3", "1e3x480"]
)
BAD_LENGTH_UNITS = st.one_of(
    st.sampled_from(["", "km", "metres", "0", "-1", "nan", "inf", "1e400", "m m"]),
    st.floats(max_value=0, allow_nan=False).map(repr),
)
EXPORT = ["export", "{root}/calibration.yaml"]
EXPORT_TF = [*EXPORT, "--format", "ros-tf", "--out", "{root}/exported"]
IMPORT = ["import-calibration", "--format", "opencv", "{root}/opencv"]
IMPORT_TO = [*IMPORT, "--out", "{root}/imported.yaml"]
INSPECT = ["inspect", "{root}/model.ply", "--reference", "{root}/model.ply"]
RECORDING = ["import-recording", "{root}/idr", "--out", "{root}/rec"]
IMPORT_ROS_TO = ["import-calibration", "--format", "ros", "{root}/ros", "--out", "{root}/i.yaml"]

# (command and the context it needs, option, bad values). Every option of every subcommand is
# listed; test_every_option_is_covered checks that against the parser.
CASES = [
    (["scan"], "--object", _names(["vase", "bracket", "pebble"])),
    (["scan"], "--size", _floats(1.0)),
    (["scan"], "--views", _ints(1, 1000)),
    (["scan"], "--radius", _floats(3.0)),
    (["scan"], "--out", _paths(OUT_PATHS)),
    (["scan"], "--seed", _ints(0, 2**32 - 1)),
    (["scan"], "--hangings", _ints(1, 6)),
    (["scan"], "--operator", _names(["instructed", "random"])),
    (["scan"], "--presentation", _names(["hanging", "table", "turntable"])),
    (["scan"], "--max-extra-views", _ints(0, 1000)),
    (["scan"], "--config", _paths(PATHS)),
    (["scan"], "--calibration", _paths(PATHS)),
    (["scan"], "--driver", _names([])),
    (["scan"], "--resume", _paths(PATHS)),
    (["scan", "--force"], "--resume", _paths(["{root}/scan"])),
    (["scan", "--out", "{root}/new"], "--resume", _paths(["{root}/scan"])),
    (["scan"], "--force=yes", None),
    (["scan"], "--meshcat=1", None),
    (["scan"], "--print-config=1", None),
    (["scan"], "--plan-only=1", None),
    (["scan"], "--monitor=1", None),
    (["scan", "--monitor"], "--intruder", st.sampled_from(["", "x", "-1", "1,,2", "nan", "inf"])),
    (["scan"], "--intruder", st.just("4")),
    (["monitor"], "--duration", _floats(None)),
    (["monitor"], "--intruder", st.sampled_from(["", "x", "-1", "nan", "1;2"])),
    (["monitor", "--duration", "5"], "--intruder", st.just("6")),
    (["scan"], "--sensor", _names(["stereo", "rgbd"])),
    (["calibrate"], "--sensor", _names(["stereo", "rgbd"])),
    (["scan"], "--robot", _paths([*PATHS, "kuka", "RX60"])),
    (["calibrate"], "--robot", _paths([*PATHS, "kuka", "RX60"])),
    (["check-cell"], "--config", _paths(PATHS)),
    (["check-cell"], "--calibration", _paths(PATHS)),
    (["check-cell"], "--driver", _names([])),
    (["check-cell"], "--board=1", None),
    (["check-cell"], "--hangings", _ints(1, 6)),
    # Hosts that cannot be listened on (an empty or "0" host would listen on every interface).
    (["emulate-controller"], "--host", st.sampled_from(["no such host", "256.1.1.1", "a b"])),
    (["emulate-controller"], "--motion-port", _ints(0, 65535)),
    (["emulate-controller"], "--state-port", _ints(0, 65535)),
    (["emulate-controller"], "--time-scale", _floats(None)),
    (["monitor"], "--config", _paths(PATHS)),
    (["scan", "--plan-only"], "--resume", _paths(["{root}/scan"])),
    (["scan", "--plan-only"], "--out", _paths([*OUT_PATHS, "{root}/scan"])),
    (["calibrate"], "--out", _paths(OUT_PATHS)),
    (["calibrate"], "--config", _paths(PATHS)),
    (["calibrate"], "--force=1", None),
    (["calibrate"], "--resume", _paths(PATHS)),
    (["calibrate"], "--seed", _ints(0, 2**32 - 1)),
    (["calibrate"], "--stations", _ints(3, 1000)),
    (["calibrate"], "--driver", _names([])),
    (["calibrate"], "--board", _names(["charuco", "chessboard", "circles_asymmetric"])),
    (["calibrate"], "--board-size", _names([])),
    (["calibrate"], "--board-spacing", _floats(0.5)),
    (["calibrate"], "--marker-size", _floats(None)),
    (["calibrate", "--board", "charuco"], "--marker-size", _floats(0.02)),
    (["calibrate"], "--dictionary", _names([])),
    (["calibrate"], "--inverted=1", None),
    (["calibrate"], "--robot-offsets=1", None),
    (["calibrate"], "--offline", _paths(PATHS)),
    (["calibrate", "--offline", "{root}/foreign"], "--pose-convention", _names([])),
    (["calibrate"], "--pose-convention", st.just("kuka")),
    (["calibrate", "--offline", "{root}/foreign"], "--pose-layout", _names([])),
    (["calibrate", "--offline", "{root}/foreign"], "--euler", _names(["xyz"])),
    (["calibrate", "--offline", "{root}/foreign"], "--length-unit", _names(["m", "mm"])),
    (["calibrate", "--offline", "{root}/foreign"], "--angle-unit", _names(["deg", "rad"])),
    (["calibrate"], "--inverse-poses", None),
    (["calibrate", "--offline", "{root}/foreign"], "--pose-file", _paths(PATHS)),
    (["calibrate", "--offline", "{root}/foreign"], "--intrinsics", _paths(PATHS)),
    (["calibrate"], "--eye-to-hand=1", None),
    (["calibrate", "--eye-to-hand"], "--held-out", _ints(0, 10_000)),
    (["calibrate"], "--held-out", st.just("5")),
    (["calibrate", "--eye-to-hand"], "--grid-spacing", _floats(1.0)),
    (["calibrate", "--eye-to-hand"], "--offline", _paths(["{root}/foreign"])),
    (["reconstruct"], "", _paths(PATHS)),
    (["reconstruct", "{root}/scan"], "--config", _paths(PATHS)),
    (["reconstruct", "{root}/scan"], "--calibration", _paths(PATHS)),
    (["reconstruct", "{root}/scan"], "--out", _paths(OUT_PATHS)),
    (["reconstruct", "{root}/scan"], "--force=1", None),
    (["reconstruct", "{root}/scan"], "--no-icp=1", None),
    (["reconstruct", "{root}/scan"], "--no-handeye=1", None),
    (["reconstruct", "{root}/scan"], "--formats", _names(["ply", "obj", "stl"])),
    (["reconstruct", "{root}/scan"], "--workers", _ints(1, 1024)),
    (["reconstruct", "{root}/scan"], "--masks", _names(["all", "even", "none"])),
    (["reconstruct", "{root}/scan"], "--masks", st.just("even")),  # a scan, not a recording
    (["reconstruct", "{root}/scan"], "--volume", _floats(None)),
    (["reconstruct", "{root}/scan"], "--box", _floats(None)),
    (["reconstruct", "{root}/scan"], "--units", _names(["m", "mm"])),
    (["reconstruct", "{root}/scan"], "--frame", _names(["world", "object"])),
    (["reconstruct", "{root}/scan"], "--decimate", _ints(4, 10**8)),
    (
        ["reconstruct", "{root}/scan"],
        "--ray-address",
        st.sampled_from(["", "nowhere", "host:", ":6379", "127.0.0.1:9", "ray://127.0.0.1:9"]),
    ),
    (["merge", "--out", "{root}/m"], "", _paths([*PATHS, "{root}/scan"])),
    (["merge", "{root}/scan", "{root}/scan", "--out", "{root}/m"], "", _paths(["{root}/scan"])),
    (["merge", "{root}/scan", "{root}/scan2"], "--out", _paths(OUT_PATHS)),
    (["merge", "{root}/scan", "{root}/scan2", "--out", "{root}/m"], "--config", _paths(PATHS)),
    (["merge", "{root}/scan", "{root}/scan2", "--out", "{root}/m"], "--force=1", None),
    (["preview"], "--object", _names(["vase", "bracket", "pebble"])),
    (["preview"], "--out", _paths(OUT_PATHS)),
    (["preview"], "--force=yes", None),
    (["preview"], "--seed", _ints(0, 2**32 - 1)),
    (["export", "--format", "opencv", "--out", "{root}/exported"], "", _paths(PATHS)),
    (["export", "--format", "ros", "--out", "{root}/exported"], "", st.just("{root}/mono.yaml")),
    ([*EXPORT, "--out", "{root}/exported"], "--format", _names(["opencv", "ros", "ros-tf"])),
    ([*EXPORT, "--format", "opencv"], "--out", _paths([*OUT_PATHS, "{root}/opencv"])),
    ([*EXPORT, "--format", "ros", "--out", "{root}/ros"], "--force=1", None),
    (EXPORT_TF, "--parent-frame", BAD_FRAMES),
    (EXPORT_TF, "--child-frame", BAD_FRAMES),
    (EXPORT_TF, "--child-frame", st.just("tool0")),
    ([*EXPORT, "--format", "opencv", "--out", "{root}/e"], "--parent-frame", st.just("tool0")),
    ([*EXPORT, "--format", "ros", "--out", "{root}/e"], "--child-frame", st.just("camera")),
    (["import-calibration", "--format", "opencv", "--out", "{root}/i.yaml"], "", _paths(PATHS)),
    (["import-calibration", "--format", "ros", "--out", "{root}/i.yaml"], "", _paths(PATHS)),
    (["import-calibration", "{root}/opencv", "--out", "{root}/i.yaml"], "--format", _names([])),
    (IMPORT, "--out", _paths([*OUT_PATHS, "{root}/empty", "{root}/calibration.yaml"])),
    (IMPORT_TO, "--force=1", None),
    (IMPORT_TO, "--hand-eye", _paths([*PATHS, "{root}/calibration.yaml"])),
    (IMPORT_TO, "--image-size", BAD_IMAGE_SIZES),
    (["inspect", "--reference", "{root}/model.ply"], "", _paths(PATHS)),
    (["inspect", "{root}/model.ply"], "--reference", _paths([*PATHS, "{root}/calibration.yaml"])),
    (INSPECT, "--tolerance", _floats(None)),
    (INSPECT, "--min-within", _floats(1.0)),
    (INSPECT, "--scale", _floats(None)),
    (INSPECT, "--reference-unit", _names(["auto", "m", "mm"])),
    (INSPECT, "--align", _names(["best-fit", "none"])),
    (INSPECT, "--out", _paths(OUT_PATHS)),
    (INSPECT, "--force=1", None),
    (["view"], "", _paths(PATHS)),
    (["view", "{root}/empty"], "--no-browser=1", None),
    (IMPORT_TO, "--image-size", st.just("640x480")),
    (IMPORT_ROS_TO, "--image-size", st.just("1280x960")),
    (IMPORT_TO, "--length-unit", BAD_LENGTH_UNITS),
    (IMPORT_TO, "--length-unit", st.just("mm")),
    (IMPORT_ROS_TO, "--length-unit", st.just("m")),
    (["import-recording", "--out", "{root}/rec"], "", _paths(PATHS)),
    (
        ["import-recording", "{root}/idr"],
        "--out",
        _paths([*OUT_PATHS, "{root}/scan", "{root}/idr"]),
    ),
    (RECORDING, "--format", _names(["idr", "colmap", "plain"])),
    (RECORDING, "--scale", _floats(None)),
    (RECORDING, "--known-distance", _names([])),
    (RECORDING, "--masks", _paths(PATHS)),
]


@pytest.fixture
def no_work(monkeypatch):
    import planners.planner
    import reconstruction.calibration.file
    import scanner.calibrate.eye_to_hand
    import scanner.calibrate.offline
    import scanner.inspect.inspection
    import scanner.reconstruct.scan_views
    import scanner.recordings.scan_writer
    import scanner.scan.preview

    monkeypatch.setattr(planners.planner.Planner, "__init__", _tripwire)
    monkeypatch.setattr(scanner.inspect.inspection, "inspect_model", _tripwire)
    monkeypatch.setattr(scanner.reconstruct.scan_views, "capture_views", _tripwire)
    monkeypatch.setattr(scanner.calibrate.offline, "solve", _tripwire)
    monkeypatch.setattr(scanner.calibrate.eye_to_hand, "grid_points", _tripwire)
    monkeypatch.setattr(scanner.scan.preview, "first_reachable_view", _tripwire)
    monkeypatch.setattr(scanner.recordings.scan_writer, "write_recording_scan", _tripwire)
    # Export and import: nothing is written.
    for name in ("write_opencv_stereo", "write_ros_camera_info", "write_static_transform"):
        monkeypatch.setattr(exchange, name, _tripwire)
    monkeypatch.setattr(reconstruction.calibration.file, "save_calibration", _tripwire)


def _check(argv: list[str], option: str, value: str | None, capsys) -> None:
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's usage errors
        code = e.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, f"{argv}: exit {code}, stderr: {err}"
    assert "Traceback" not in err, err
    last = lines[-1] if lines else ""
    # argparse prints its usage above its one error line; our errors are one line.
    assert last.startswith("scanner") and "error:" in last, err
    if not last.startswith("scanner: error:"):
        return  # argparse names the option itself
    name = option.split("=")[0]
    # The option itself, or its concept in the message ("unknown pose convention ...").
    named = [name, name.lstrip("-").replace("-", " "), name.lstrip("-").replace("-", "_")]
    named = [n for n in named if n]
    if value:
        named += [value, value.strip()]
    low = last.lower()
    assert any(n and n.lower() in low for n in named) or _names_a_field(last), f"{argv}: {last}"


def _names_a_field(line: str) -> bool:
    """Our checks name the configuration field (section.name) the option sets."""
    return any(f in line for f in ("board", "views.", "stations.", "eye_to_hand."))


@pytest.mark.parametrize("command, option, values", CASES, ids=[f"{c[0]} {o}" for c, o, _ in CASES])
def test_bad_option_values_are_one_line_errors(command, option, values, places, no_work, capsys):
    def argv(value):
        base = [c.replace("{root}", str(places)) for c in command]
        if value is None:
            return [*base, option]
        value = value.replace("{root}", str(places))
        return [*base, value] if option == "" else [*base, option, value]

    if values is None:
        _check(argv(None), option, None, capsys)
        return

    @settings(
        max_examples=12,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.function_scoped_fixture],
    )
    @given(values)
    def check(value):
        _check(argv(value), option, value.replace("{root}", str(places)), capsys)

    check()


def test_every_option_is_covered():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    covered = {(c[0], o.split("=")[0]) for c, o, _ in CASES}
    for name, command in sub.choices.items():
        for action in command._actions:
            for flag in action.option_strings or [""]:
                if flag in ("-h", "--help"):
                    continue
                if not action.option_strings and action.dest == "help":
                    continue
                assert (name, flag) in covered, f"scanner {name} {flag or action.dest} untested"


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_unreadable_config_is_a_one_line_error(tmp_path, capsys):
    path = tmp_path / "secret.yaml"
    path.write_text(yaml.safe_dump({"views": {"count": 5}}))
    path.chmod(0)
    _check(["scan", "--config", str(path)], "--config", str(path), capsys)


@pytest.mark.parametrize(
    "argv",
    [
        ["reconstruct", "{root}/scan"],
        ["scan", "--out", "{root}/fresh", "--views", "3"],
        ["merge", "{root}/scan", "{root}/scan2", "--out", "{root}/merged"],
        ["export", "{root}/calibration.yaml", "--format", "ros-tf", "--out", "{root}/tf"],
        ["export", "{root}/calibration.yaml", "--format", "opencv", "--out", "{root}/cv"],
        [*IMPORT, "--out", "{root}/imported.yaml", "--hand-eye", "{root}/he.yaml"],
        [*IMPORT, "--out", "{root}/imported.yaml", "--image-size", "1280x960"],
        ["import-calibration", "--format", "ros", "{root}/ros", "--out", "{root}/imported.yaml"],
        RECORDING,
    ],
)
def test_valid_values_reach_the_tripwire(argv, places, no_work):
    # The control: with valid values the work starts, so the cases above would notice a bad
    # value that slips through.
    with pytest.raises(WorkStartedError):
        main([a.replace("{root}", str(places)) for a in argv])
