"""What a command is given is checked before any work starts: what a configuration or a flag
names (object, calibration file, driver) is loaded when the configuration is, relative paths in
a configuration are read from its folder, `--driver` modules are found from the working folder
as the guide shows, and check-cell takes the scan options it checks for. Third-party console
messages stay off the terminal, and `view` says "opened" only when a browser started."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from reconstruction.calibration.file import Calibration, save_calibration
from reconstruction.common.transforms import make_pose
from scanner.commands.main import main
from scanner.configs.scan import ScanConfig
from tests.test_example_configs import write_nominal_calibration
from tests.tiny_scan import TINY_SCAN

# The installed console script: unlike `python -m scanner`, it does not put the working folder
# on the import path.
SCANNER = Path(sys.executable).parent / "scanner"


def _one_line(capsys) -> str:
    (line,) = capsys.readouterr().err.splitlines()
    return line


def _scanner(*args: str, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(SCANNER), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    "flag, value, needle",
    [
        ("--object", "no-such-object", "unknown object 'no-such-object'"),
        ("--object", "missing.stl", "no such mesh file"),
        ("--driver", "no_such_cell.rx60:connect", "cannot import 'no_such_cell.rx60'"),
        ("--driver", "tests.simulated_hardware:no_factory", "has no callable 'no_factory'"),
        ("--driver", "just-a-name", "expected 'package.module:factory'"),
        ("--calibration", "missing.yaml", "missing.yaml"),
    ],
)
def test_print_config_validates_what_it_prints(flag, value, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["scan", "--print-config", flag, value]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.splitlines()
    assert line.startswith(f"scanner: error: {flag}: ") and needle in line, line


def test_print_config_refuses_an_implausible_calibration_as_a_refused_result(tmp_path, capsys):
    stereo = ScanConfig().camera.stereo_camera()
    far = make_pose(np.eye(3), [0.0, 1.5, 0.0])  # the camera 1.5 m off the flange
    path = save_calibration(Calibration(far, stereo, stereo.left), tmp_path / "far.yaml")
    assert main(["scan", "--print-config", "--calibration", str(path)]) == 3
    line = _one_line(capsys)
    assert "--calibration" in line and "1500 mm from the flange" in line


def test_a_surface_that_is_not_built_is_refused_at_load(tmp_path, capsys):
    path = tmp_path / "scan.yaml"
    path.write_text("processing:\n  primary_surface: marching\n")
    assert main(["scan", "--config", str(path), "--print-config"]) == 2
    line = _one_line(capsys)
    assert line.startswith(f"scanner: error: {path}: processing.primary_surface: "), line
    assert "'marching'" in line and "poisson" in line


def test_relative_paths_are_read_from_the_configuration_s_folder(tmp_path, capsys, monkeypatch):
    cell = tmp_path / "cell"
    write_nominal_calibration(cell / "calibration" / "cal.yaml")
    config = cell / "scan.yaml"
    config.write_text("calibration_file: calibration/cal.yaml\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["scan", "--config", str(config), "--print-config"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["calibration_file"] == str(cell / "calibration" / "cal.yaml")
    # A missing one is named by the file, the key and where it was looked for.
    config.write_text("calibration_file: calibration/other.yaml\n")
    assert main(["scan", "--config", str(config), "--print-config"]) == 2
    line = _one_line(capsys)
    assert line.startswith(f"scanner: error: {config}: calibration_file: "), line
    assert str(cell / "calibration" / "other.yaml") in line


def test_every_path_key_is_resolved_and_nothing_else():
    from scanner.configs.references import resolve_relative_paths

    folder = Path("/configs")
    data = {
        "object": "parts/bracket.stl",
        "calibration_file": "cal.yaml",
        "planner": {"cache_dir": "roadmaps"},
        "hardware": {"camera": {"left": "rec/left_%04d.png", "right": 1}},
    }
    resolved = resolve_relative_paths(data, folder)
    assert resolved == {
        "object": "/configs/parts/bracket.stl",
        "calibration_file": "/configs/cal.yaml",
        "planner": {"cache_dir": "/configs/roadmaps"},
        "hardware": {"camera": {"left": "/configs/rec/left_%04d.png", "right": 1}},
    }
    assert data["calibration_file"] == "cal.yaml"  # the file's own mapping is left alone
    # Names, device paths, URLs and absolute paths are not files beside the configuration.
    kept = {
        "object": "vase",
        "calibration_file": "/abs/cal.yaml",
        "hardware": {"camera": {"left": "rtsp://cam/left.sdp", "right": "/dev/video1"}},
    }
    assert resolve_relative_paths(kept, folder) == kept


def test_a_driver_module_is_found_from_the_working_folder(tmp_path):
    package = tmp_path / "my_cell"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "rx60.py").write_text("def connect(config):\n    return 'not a cell'\n")
    r = _scanner("scan", "--print-config", "--driver", "my_cell.rx60:connect", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert yaml.safe_load(r.stdout)["driver"] == "my_cell.rx60:connect"
    # A scan imports it and calls its factory (whose answer, not a Hardware, is refused).
    r = _scanner(
        "scan", "--driver", "my_cell.rx60:connect", "--hangings", "1", "--out", "s", cwd=tmp_path
    )
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        "scanner: error: driver: my_cell.rx60:connect returned str; expected "
        "robots.drivers.interfaces.Hardware holding a RobotDriver and a StereoCameraDriver"
    ]


def test_check_cell_takes_the_hangings_it_checks_for(tmp_path, capsys, monkeypatch):
    config = tmp_path / "tiny.yaml"
    tiny = copy.deepcopy(TINY_SCAN)
    del tiny["hangings"]  # auto: the driver would have to ask for re-hangs
    config.write_text(yaml.safe_dump(tiny))
    argv = ["check-cell", "--config", str(config), "--driver", "tests.simulated_hardware:connect"]
    assert main(argv) == 2
    line = _one_line(capsys)
    assert "hangings: 'auto' needs a driver that can ask for a re-hang" in line
    assert "--hangings 1" in line
    # The advice works: check-cell has the option.
    code = main([*argv, "--hangings", "1"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.splitlines()[-1] == "READY: a scan can start"


def test_open3d_s_reader_messages_stay_off_the_terminal(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_text("not a mesh\n")
    r = _scanner("inspect", str(bad), "--reference", str(bad), cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        f"scanner: error: model {bad}: no triangles read (expected a .ply/.obj/.stl mesh)"
    ]
    r = _scanner("scan", "--print-config", "--object", str(bad), cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
    assert "RPly" not in r.stderr


@pytest.mark.parametrize("browser_exit, said", [(3, "model page"), (0, "opened")])
def test_view_says_opened_only_when_a_browser_started(tmp_path, browser_exit, said):
    """A display is set and xdg-open exists, but it fails (no browser behind it): Python's
    webbrowser calls that opened; the page's path is printed instead."""
    result = tmp_path / "inspection"
    result.mkdir()
    (result / "inspection.json").write_text("{}")
    (result / "model.html").write_text("<html></html>")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    launcher = bin_dir / "xdg-open"
    launcher.write_text(f"#!/bin/sh\nsleep 0.3\nexit {browser_exit}\n")
    launcher.chmod(0o755)
    env = {
        "PATH": f"{bin_dir}{os.pathsep}/usr/bin{os.pathsep}/bin",
        "DISPLAY": ":99",
        "HOME": str(tmp_path),
        "BROWSER": str(launcher),  # chosen before any browser installed here
        **{k: v for k, v in os.environ.items() if k == "PYTHONPATH"},
    }
    r = _scanner("view", str(result), cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [f"{said}: {(result / 'model.html').resolve()}"]
