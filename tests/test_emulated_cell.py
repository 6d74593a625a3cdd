"""A whole scan over the wire: `scanner scan` with a hardware: section drives the controller
emulator over TCP and renders the cell at the joints the state port reports. It reaches the same
views and the same model as the simulator-driven scan; check-cell passes against it; a link that
fails mid-scan interrupts the scan, which resumes; bad hardware configurations are one line.

The commands run in the test's process (`tests.in_process`): the emulator serves them from its
own threads over TCP exactly as it would serve another process. The scan whose link is cut runs
in a process of its own, as on a real cell: the cut must not wait for the scan's hold on this
interpreter (in process, it came at other moments and the driver saw it another way)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from reconstruction.calibration.file import load_calibration
from reconstruction.common.transforms import pose_difference
from robots.emulator.val3_server import EmulatorSettings, Val3Emulator
from robots.simulation.cell import HOME_Q
from tests.calibration_runs import SMALL, small
from tests.in_process import scanner
from tests.tiny_scan import TINY_SCAN

pytestmark = pytest.mark.slow


def emulator_settings(**fields) -> EmulatorSettings:
    return replace(
        EmulatorSettings(),
        motion_port=0,
        state_port=0,
        connect_delay_s=0.05,
        time_scale=20.0,
        **fields,
    )


def hardware_config(tmp_path: Path, em: Val3Emulator, name: str = "cell.yaml", **extra) -> Path:
    config = dict(TINY_SCAN) | {
        "hardware": {
            "robot": {
                "host": "127.0.0.1",
                "motion_port": em.motion_address[1],
                "state_port": em.state_address[1],
                "speed_fraction": 0.5,
                # The emulator runs in this process, beside the command under test and another
                # test worker on two cores: a STATUS message can be late by more than the real
                # link's 0.5 s without any fault. The age limits themselves are tested against
                # a scripted controller (test_val3_faults.py).
                "state_timeout_s": 2.0,
            },
            "camera": {"kind": "simulated"},
        }
    }
    config |= extra
    path = tmp_path / name
    path.write_text(yaml.safe_dump(config))
    return path


def capture_joints(folder: Path) -> dict[int, np.ndarray]:
    """The joints of every capture of a scan or calibration folder, by view (station)."""
    out = {}
    for entry in sorted((folder / "captures").iterdir()):
        pose = yaml.safe_load((entry / "capture.yaml").read_text())
        out[int(pose["pose_index"])] = np.array(pose["q_rad"], float)
    return out


def views_and_joints(scan_dir: Path) -> dict[int, np.ndarray]:
    manifest = yaml.safe_load((scan_dir / "scan.yaml").read_text())
    assert manifest["status"] in ("complete", "reconstructed")
    return capture_joints(scan_dir)


def test_a_scan_over_the_wire_matches_the_simulated_scan(tiny_scan, tmp_path, capfd):
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        config = hardware_config(tmp_path, em)
        r = scanner(capfd, "scan", "--config", config, "--out", tmp_path / "s")
        assert r.returncode == 0, r.stderr
        # Every point the controller got was a checked joint-linear waypoint at the speed
        # asked for, and the arm stopped nowhere else.
        assert em.received and all(p.velocity == pytest.approx(0.5) for p in em.received)
    wire = views_and_joints(tmp_path / "s")
    simulated = views_and_joints(tiny_scan.scan_dir)
    assert sorted(wire) == sorted(simulated)
    for view, q in wire.items():
        # float32 on the wire: the arm arrives within 1e-6 rad of where the simulator's did
        assert np.abs(q - simulated[view]).max() < 1e-5
    # The images: rendered at joints 1e-8 rad apart, equal but for a few edge pixels.
    for view in wire:
        for side in ("left.png", "right.png"):
            a = cv2.imread(str(tmp_path / "s" / "captures" / f"{view:04d}" / side))
            b = cv2.imread(str(tiny_scan.scan_dir / "captures" / f"{view:04d}" / side))
            assert np.abs(a.astype(int) - b).mean() < 0.01
    # The models, built by the same chain (the scan's own reconstruction) from both scans.
    # Five 320x240 views leave the hand-eye correction ill-conditioned (not converged; 3-7 mm
    # either way from such tiny image differences): the tiny scan keeps the mount as
    # calibrated, so both models are compared with it.
    observed = {}
    wire = json.loads((tmp_path / "s" / "results" / "report.json").read_text())
    for name, report in (("wire", wire), ("simulated", tiny_scan.report)):
        assert report["handeye_error_mm"] == report["handeye_error_before_mm"], name
        observed[name] = {k: v["chamfer_observed_mm"] for k, v in report["surfaces"].items()}
    assert set(observed["wire"]) == set(observed["simulated"]) == {"fused_cloud", "poisson", "tsdf"}
    for surface, chamfer_mm in observed["simulated"].items():
        # measured: fused cloud within 0.1 %, TSDF 0.1-1.8 %, Poisson 2.4 %
        rel = 0.02 if surface == "fused_cloud" else 0.05
        assert observed["wire"][surface] == pytest.approx(chamfer_mm, rel=rel), surface


def test_check_cell_passes_against_the_emulator_and_fails_on_an_emergency_stop(tmp_path, capfd):
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        config = hardware_config(tmp_path, em)
        r = scanner(capfd, "check-cell", "--config", config)
        assert r.returncode == 0, r.stdout + r.stderr
        lines = r.stdout.splitlines()
        for item in ("robot link", "controller", "joints", "camera", "exposure", "sharpness"):
            assert any(line.startswith("ok") and item in line for line in lines), item
        assert any(line.startswith("ok") and "first move" in line for line in lines)
        assert lines[-1] == "READY: a scan can start"
        assert em.received == []  # nothing was sent to the motion port: nothing moved
        em.e_stop()
        r = scanner(capfd, "check-cell", "--config", config)
        assert r.returncode == 4
        assert any(
            line.startswith("FAIL") and "emergency stop" in line for line in r.stdout.splitlines()
        )
        assert r.stdout.splitlines()[-1].startswith("NOT READY: controller")
        assert np.abs(em.joint_positions() - HOME_Q).max() < 1e-6


def scanner_process(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "scanner", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=900,
    )


def test_a_link_lost_mid_scan_interrupts_it_and_the_scan_resumes(tmp_path, capfd):
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        config = hardware_config(tmp_path, em, reconstruct=False)
        # The connections drop as the arm starts its first motion after a capture: a watcher,
        # as a cable pulled out would.
        done = threading.Event()
        captures = tmp_path / "s" / "captures"

        def pull_the_cable():
            while not done.is_set() and not (captures.exists() and any(captures.iterdir())):
                done.wait(0.005)
            points = len(em.received)
            while not done.is_set() and len(em.received) == points:
                done.wait(0.001)
            em.drop_connections()

        watcher = threading.Thread(target=pull_the_cable, daemon=True)
        watcher.start()
        r = scanner_process("scan", "--config", config, "--out", tmp_path / "s")
        done.set()
        watcher.join()
        assert r.returncode == 5, r.stderr
        message = r.stderr.strip().splitlines()
        assert len(message) == 1 and "Traceback" not in r.stderr
        assert "robot link" in message[0] and "scanner scan --resume" in message[0]
        manifest = yaml.safe_load((tmp_path / "s" / "scan.yaml").read_text())
        assert manifest["status"] == "interrupted"
        kept = set(views_and_joints_partial(tmp_path / "s"))
        r = scanner(capfd, "scan", "--resume", tmp_path / "s")
        assert r.returncode == 0, r.stderr
        assert kept < set(views_and_joints_partial(tmp_path / "s"))


def views_and_joints_partial(scan_dir: Path) -> list[int]:
    return [
        int(yaml.safe_load((e / "capture.yaml").read_text())["pose_index"])
        for e in (scan_dir / "captures").iterdir()
        if (e / "capture.yaml").exists()
    ]


@pytest.mark.parametrize(
    "hardware, expected",
    [
        ({"robot": {"kind": "kuka"}}, "hardware.robot.kind: 'kuka' is not one of staubli_val3"),
        ({"camera": {"kind": "opencv", "right": None}}, "hardware.camera.right: expected"),
        ({"robot": {"motion_port": "eleven"}}, "hardware.robot.motion_port: expected an integer"),
        (
            {"camera": {"kind": "opencv", "left": "missing_%04d.png", "right": "m_%04d.png"}},
            # A recording's relative path is read from the configuration's folder.
            "hardware.camera.left: cannot open '{folder}/missing_%04d.png'",
        ),
    ],
)
def test_bad_hardware_sections_are_one_line_and_nothing_moves(tmp_path, capfd, hardware, expected):
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        base = {
            "robot": {"motion_port": em.motion_address[1], "state_port": em.state_address[1]},
            "camera": {"kind": "simulated"},
        }
        section = {k: base[k] | hardware.get(k, {}) for k in base}
        path = tmp_path / "bad.yaml"
        path.write_text(yaml.safe_dump(dict(TINY_SCAN) | {"hardware": section}))
        r = scanner(capfd, "scan", "--config", path, "--out", tmp_path / "s")
        assert r.returncode == 2, r.stderr
        expected = expected.replace("{folder}", str(tmp_path))
        assert expected in r.stderr and len(r.stderr.strip().splitlines()) == 1
        assert em.received == []


def test_an_unreachable_controller_stops_the_scan_before_anything(tmp_path, capfd):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    path = tmp_path / "cell.yaml"
    hardware = {
        "robot": {"motion_port": port, "connect_timeout_s": 0.5},
        "camera": {"kind": "simulated"},
    }
    path.write_text(yaml.safe_dump(dict(TINY_SCAN) | {"hardware": hardware}))
    for command in ("scan", "check-cell"):
        args = ["--config", path] + (["--out", tmp_path / "s"] if command == "scan" else [])
        r = scanner(capfd, command, *args)
        assert r.returncode == 2
        assert r.stderr.strip() == (
            f"scanner: error: hardware.robot.motion_port: cannot connect to 127.0.0.1:{port} "
            "(Connection refused); expected the VAL 3 ROS server of the arm's controller"
        )
        assert not (tmp_path / "s").exists()


def _recording(folder: Path, size: tuple[int, int], frames: int = 3) -> dict:
    """A recorded stereo pair sequence (textured, well exposed) as OpenCV reads it back."""
    rng = np.random.default_rng(0)
    folder.mkdir()
    for k in range(frames):
        for side in ("left", "right"):
            texture = rng.integers(40, 220, (size[1] // 4, size[0] // 4, 3), dtype=np.uint8)
            image = cv2.resize(texture, size, interpolation=cv2.INTER_NEAREST)
            cv2.imwrite(str(folder / f"{side}_{k:04d}.png"), image)
    return {
        "kind": "opencv",
        "left": str(folder / "left_%04d.png"),
        "right": str(folder / "right_%04d.png"),
    }


def test_check_cell_with_a_recorded_opencv_camera(tmp_path, capfd):
    """The OpenCV camera path end to end: a recording of the calibrated size passes; one of
    another size is refused in one line before anything moves."""
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        width, height = TINY_SCAN["camera"]["width_px"], TINY_SCAN["camera"]["height_px"]
        for name, size, code in (("good", (width, height), 0), ("small", (160, 120), 2)):
            camera = _recording(tmp_path / name, size)
            path = hardware_config(tmp_path, em, f"{name}.yaml")
            config = yaml.safe_load(path.read_text())
            config["hardware"]["camera"] = camera
            path.write_text(yaml.safe_dump(config))
            r = scanner(capfd, "check-cell", "--config", path)
            assert r.returncode == code, r.stdout + r.stderr
            if code == 0:
                assert f"ok    camera       a pair of {width}x{height} images" in r.stdout
            else:
                assert r.stderr.strip() == (
                    "scanner: error: hardware.camera.left: delivers 160x120 images, the "
                    f"calibration expects {width}x{height}"
                )
        assert em.received == []


def test_calibrate_over_the_wire(tmp_path, capfd, run_dir):
    """`scanner calibrate` with a hardware: section: the stations are visited through the
    controller emulator and the board is seen by the simulated camera at the reported joints;
    the hand-eye result is the simulation's (the shared small run: tests/calibration_runs.py;
    how close that is to the truth is bench_calibration.py's)."""
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        path = tmp_path / "calibrate.yaml"
        camera = SMALL.camera
        config = {
            "stations": {"count": SMALL.stations.count},
            "camera": {
                "width_px": camera.width_px,
                "height_px": camera.height_px,
                "focal_px": camera.focal_px,
            },
            "hardware": {
                "robot": {
                    "motion_port": em.motion_address[1],
                    "state_port": em.state_address[1],
                    "speed_fraction": 0.5,
                },
                "camera": {"kind": "simulated"},
            },
        }
        path.write_text(yaml.safe_dump(config))
        r = scanner(capfd, "calibrate", "--config", path, "--out", tmp_path / "cal")
        assert r.returncode == 0, r.stdout + r.stderr
        assert em.received and all(p.velocity == pytest.approx(0.5) for p in em.received)
    report = json.loads((tmp_path / "cal" / "results" / "report.json").read_text())
    assert report["poses_used"] == SMALL.stations.count and report["stations_skipped"] == []
    simulated = small(run_dir)
    # The arm stood where the simulated arm did (float32 on the wire: within 1e-6 rad) and the
    # camera saw what the simulated one saw there: the same X_FC but for what such tiny image
    # differences move it (measured 0.01 mm / 0.001 deg; the nominal mount is 3 mm / 1 deg off).
    wire_q, simulated_q = capture_joints(tmp_path / "cal"), capture_joints(simulated.out_dir)
    assert sorted(wire_q) == sorted(simulated_q)
    for station, q in wire_q.items():
        assert np.abs(q - simulated_q[station]).max() < 1e-5
    X_FC = load_calibration(tmp_path / "cal" / "results" / "calibration.yaml").X_FC
    dt, dr = pose_difference(X_FC, simulated.solution.hand_eye.X_FC)
    assert dt < 0.05e-3 and dr < np.radians(0.01), (dt, dr)
    assert report["truth"]["handeye_error_mm"] == pytest.approx(
        simulated.report["truth"]["handeye_error_mm"], abs=0.1
    )


@pytest.mark.parametrize(
    "sensor, expected",
    [
        ("stereo", "hardware.camera.kind: 'realsense' is an RGB-D camera (sensor: rgbd)"),
        ("rgbd", "hardware.camera: no RealSense device found"),
    ],
)
def test_a_realsense_that_is_not_there_or_not_the_sensor_is_one_line(
    tmp_path, capfd, sensor, expected
):
    with Val3Emulator(emulator_settings(), HOME_Q).start() as em:
        path = hardware_config(tmp_path, em, sensor=sensor)
        config = yaml.safe_load(path.read_text())
        config["hardware"]["camera"] = {"kind": "realsense"}
        path.write_text(yaml.safe_dump(config))
        r = scanner(capfd, "scan", "--config", path, "--out", tmp_path / "s")
        assert r.returncode == 2, r.stderr
        expected = expected.replace("{folder}", str(tmp_path))
        assert expected in r.stderr and len(r.stderr.strip().splitlines()) == 1
        assert em.received == [] and not (tmp_path / "s").exists()
