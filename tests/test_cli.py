"""The command line: help texts and one-line user errors with exit code 2.

The commands run in the test's process (`tests.in_process`) but for `python -m scanner
--version`, which checks the module's own entry point."""

import subprocess
import sys

import pytest

from scanner.commands.main import main
from tests.in_process import scanner


@pytest.mark.parametrize("args", [[], ["scan"], ["calibrate"], ["reconstruct"], ["preview"]])
def test_help(args, capsys):
    with pytest.raises(SystemExit) as e:
        main([*args, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "usage: scanner" in out
    if not args:
        for sub in ("scan", "calibrate", "reconstruct"):
            assert sub in out


@pytest.mark.parametrize(
    "args, needle",
    [
        (["preview", "--object", "teacup"], "unknown object 'teacup'"),
        (["preview", "--object", "/nonexistent/mesh.stl"], "no such mesh file"),
    ],
)
def test_user_errors_are_one_line_exit_2(args, needle, tmp_path, capfd):
    r = scanner(capfd, *args, "--out", tmp_path / "o")
    assert r.returncode == 2
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_preview_writes_pngs(tmp_path, capfd):
    import cv2

    r = scanner(capfd, "preview", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    left = cv2.imread(str(tmp_path / "left.png"))
    assert left.shape == (960, 1280, 3)
    assert cv2.imread(str(tmp_path / "overview.png")) is not None


@pytest.mark.parametrize("command", [["reconstruct"], ["scan", "--resume"]])
def test_a_folder_that_is_not_a_scan_is_refused(command, tmp_path, capfd):
    (tmp_path / "holiday.jpg").write_bytes(b"not a scan")
    r = scanner(capfd, *command, tmp_path)
    assert r.returncode == 2
    assert "not a scan directory" in r.stderr and "Traceback" not in r.stderr
    assert (tmp_path / "holiday.jpg").read_bytes() == b"not a scan"


def test_printed_config_loads_back_as_the_same_configuration(tmp_path, capfd):
    from scanner.configs.scan import (
        ScanConfig,
        load_scan_config,
        scan_config_to_dict,
        with_overrides,
    )

    r = scanner(capfd, "scan", "--print-config", "--views", "7", "--object", "bracket")
    assert r.returncode == 0, r.stderr
    path = tmp_path / "scan.yaml"
    path.write_text(r.stdout)
    config = load_scan_config(path)
    assert config.views.count == 7 and config.object == "bracket"
    expected = with_overrides(ScanConfig(), object_spec="bracket", views=7)
    assert scan_config_to_dict(config) == scan_config_to_dict(expected)
    bad = tmp_path / "bad.yaml"
    bad.write_text(r.stdout.replace("radius_m: 0.5", "radius_mm: 500"))
    r = scanner(capfd, "scan", "--config", bad, "--print-config")
    assert r.returncode == 2 and "unknown key(s) radius_mm" in r.stderr


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--offline", ".", "--driver", "m:f"], "do not give --driver"),
        (["--eye-to-hand", "--driver", "tests.simulated_hardware:connect"], "simulator only"),
    ],
)
def test_calibrate_driver_misuse_is_refused(args, needle, tmp_path, capfd):
    r = scanner(capfd, "calibrate", *args, "--out", tmp_path / "out")
    assert r.returncode == 2 and needle in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()


def test_version_is_the_installed_package_version():
    from importlib.metadata import version

    r = subprocess.run(
        [sys.executable, "-m", "scanner", "--version"], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"scanner {version('scanner')}"


def test_seed_and_preview_help_state_their_defaults():
    from scanner.commands.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for command, options in (
        ("scan", ["--seed"]),
        ("calibrate", ["--seed"]),
        ("preview", ["--object", "--out", "--seed"]),
    ):
        seen = set()
        for action in sub.choices[command]._actions:
            if set(action.option_strings) & set(options):
                seen |= set(action.option_strings)
                # As --help prints it (some defaults are read from the configuration).
                text = sub.choices[command]._get_formatter()._expand_help(action)
                assert "(default " in text, f"{command} {action.option_strings}: {text}"
        assert seen >= set(options)
