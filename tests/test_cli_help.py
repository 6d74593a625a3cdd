"""The command line's help states every option's default (read from the configuration records,
not copied), and its errors are one line naming what the user typed: the flag, or the file then
the key path in it."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from dataclasses import replace

import pytest

from reconstruction.calibration.pose_files import PoseFormat
from reconstruction.common.errors import ScannerError
from scanner.calibrate.config import CalibrateConfig
from scanner.commands.arguments import ScannerArgumentParser
from scanner.commands.main import build_parser, main
from scanner.configs.scan import ProcessingConfig, ScanConfig, load_scan_config


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _help(command: argparse.ArgumentParser, flag: str) -> str:
    """An option's help as `--help` prints it (%(...)s expanded), on one line."""
    action = next(a for a in command._actions if flag in a.option_strings)
    return " ".join(command._get_formatter()._expand_help(action).split())


def _options():
    for name, command in _commands().items():
        for action in command._actions:
            flags = set(action.option_strings)
            if flags and not flags & {"-h", "--help", "--version"}:
                yield name, command, action


def test_every_option_states_its_default():
    # Options added later are caught too: the list comes from the parser.
    missing = []
    for name, command, action in _options():
        text = _help(command, action.option_strings[0])
        if isinstance(action, argparse._StoreTrueAction):
            ok = "(default: off" in text
        elif action.required:
            ok = "no default" in text
        else:
            ok = re.search(r"\(default\b", text) is not None
        if not ok:
            missing.append(f"scanner {name} {action.option_strings[0]}: {text!r}")
    assert not missing, "help without its default:\n" + "\n".join(missing)


def test_every_subcommand_parser_has_one_line_errors():
    for name, command in _commands().items():
        assert isinstance(command, ScannerArgumentParser), name


SCAN, CALIBRATE = ScanConfig(), CalibrateConfig()


@pytest.mark.parametrize(
    "command, flag, expected",
    [
        ("scan", "--object", SCAN.object),
        ("scan", "--size", SCAN.cell.object_size_m),
        ("scan", "--views", SCAN.views.count),
        ("scan", "--radius", SCAN.views.radius_m),
        ("scan", "--seed", SCAN.error_model.seed),
        ("scan", "--max-extra-views", SCAN.views.max_extra_views),
        ("scan", "--hangings", SCAN.hangings),
        ("calibrate", "--seed", CALIBRATE.error_model.seed),
        ("calibrate", "--stations", CALIBRATE.stations.count),
        ("calibrate", "--board", CALIBRATE.board.kind),
        ("calibrate", "--board-size", f"{CALIBRATE.board.cols}x{CALIBRATE.board.rows}"),
        ("calibrate", "--board-spacing", CALIBRATE.board.spacing_m),
        ("calibrate", "--marker-size", CALIBRATE.board.marker_m),
        ("calibrate", "--dictionary", CALIBRATE.board.dictionary),
        ("calibrate", "--pose-layout", PoseFormat().layout),
        ("calibrate", "--euler", PoseFormat().euler),
        ("calibrate", "--length-unit", PoseFormat().length_unit),
        ("calibrate", "--angle-unit", PoseFormat().angle_unit),
        ("calibrate", "--held-out", CALIBRATE.eye_to_hand.held_out),
        ("calibrate", "--grid-spacing", CALIBRATE.eye_to_hand.grid_spacing_m),
        (
            "reconstruct",
            "--formats",
            ",".join(s.lstrip(".") for s in ProcessingConfig().mesh_formats),
        ),
    ],
)
def test_help_defaults_are_the_configurations(command, flag, expected):
    text = _help(_commands()[command], flag)
    # A length's default says its unit.
    assert re.search(rf"\bdefault {re.escape(str(expected))}( m)?[,;)]", text), text


def test_help_defaults_follow_the_record(monkeypatch):
    # The default is read from the record when help is printed, not a copied literal.
    import scanner.configs.scan

    changed = replace(ScanConfig(), hangings=3)
    assert ScanConfig().hangings != changed.hangings
    monkeypatch.setattr(scanner.configs.scan, "ScanConfig", lambda: changed)
    assert f"(default {changed.hangings})" in _help(_commands()["scan"], "--hangings")


def test_building_the_parser_leaves_the_configurations_unimported():
    # The configuration modules import Drake and Open3D; --version and usage errors should not
    # wait for them, so help defaults are read only when help is printed.
    code = (
        "import sys; from scanner.commands.main import build_parser; build_parser(); "
        "heavy = ('pydrake', 'scanner.configs.scan', 'scanner.calibrate.config', "
        "'robots.simulation.truth'); "
        "print([m for m in heavy if m in sys.modules])"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def _one_line_error(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's usage errors
        code = e.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    return code, lines[0]


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "yaml_text, expected",
    [
        ("views:\n  cuont: 3\n", "views: unknown key(s) cuont (did you mean count?); valid keys: "),
        ("views:\n  count: 0\n", "views.count: at least 1 view is needed, got 0"),
        ("hangings: 9\n", "hangings: expected 'auto' or an integer in [1, 6], got 9"),
        (
            "hangings: sometimes\n",
            "hangings: expected 'auto' or an integer in [1, 6], got 'sometimes'",
        ),
        (
            "processing:\n  reconstruction:\n    icp:\n      enabled: 3\n",
            "processing.reconstruction.icp.enabled: expected true or false, got 3",
        ),
        ("cell:\n  object_center_m: [0.5, 0]\n", "cell.object_center_m: expected 3 values, got 2"),
        ("views:\n  center_m: [0.5, 0, no]\n", "views.center_m[2]: expected a number, got False"),
        (
            "processing:\n  mesh_formats: [.xyz]\n",
            "processing.mesh_formats: '.xyz' not known; expected suffixes from .ply, .obj, .stl",
        ),
        ("- 1\n", "expected a mapping, got [1]"),
    ],
)
def test_config_errors_give_the_file_then_the_key_path(yaml_text, expected, tmp_path):
    path = _write(tmp_path / "scan.yaml", yaml_text)
    with pytest.raises(ScannerError) as e:
        load_scan_config(path)
    assert str(e.value).startswith(f"{path}: {expected}"), str(e.value)


def test_unknown_key_lists_the_valid_ones_through_the_cli(tmp_path, capsys):
    path = _write(tmp_path / "typo.yaml", "views:\n  cuont: 3\n")
    code, line = _one_line_error(["scan", "--print-config", "--config", str(path)], capsys)
    assert code == 2
    assert line.startswith(f"scanner: error: {path}: views: unknown key(s) cuont"), line
    valid = line.split("valid keys: ")[1].split(", ")
    assert "count" in valid and "radius_m" in valid and "cuont" not in valid


@pytest.mark.parametrize(
    "argv, flag, expected",
    [
        (["scan", "--print-config", "--views", "0"], "--views", "at least 1 view"),
        (["scan", "--print-config", "--hangings", "9"], "--hangings", "in [1, 6], got 9"),
        (["scan", "--print-config", "--max-extra-views", "-1"], "--max-extra-views", "got -1"),
        (["scan", "--print-config", "--seed", "-1"], "--seed", "got -1"),
        # A bare number is metres; where that reading is implausible both readings are given.
        (["scan", "--print-config", "--size", "9"], "--size", "9 reads as 9 m (9000 mm)"),
        (["scan", "--print-config", "--radius", "9"], "--radius", "write 9mm (0.009 m)"),
        (["calibrate", "--stations", "1"], "--stations", "at least 3 stations, got 1"),
        (["calibrate", "--board", "foo"], "--board", "'foo' is not one of"),
        (["calibrate", "--board-size", "1x1"], "--board-size", "expected 2 to 200 along a side"),
        (["calibrate", "--board-spacing", "0.9"], "--board-spacing", "got 0.9"),
        (["calibrate", "--eye-to-hand", "--held-out", "-1"], "--held-out", "got -1"),
        (["calibrate", "--eye-to-hand", "--grid-spacing", "5"], "--grid-spacing", "got 5.0"),
        (["calibrate", "--offline", "{tmp}", "--pose-layout", "xyz"], "--pose-layout", "'xyz'"),
        (["calibrate", "--offline", "{tmp}", "--euler", "xx"], "--euler", "'xx'"),
        (["calibrate", "--offline", "{tmp}", "--angle-unit", "grad"], "--angle-unit", "'grad'"),
        (["calibrate", "--offline", "{tmp}", "--pose-convention", "k"], "--pose-convention", "k"),
    ],
)
def test_bad_flag_values_name_the_flag_not_the_config_key(argv, flag, expected, tmp_path, capsys):
    (tmp_path / "in").mkdir()
    argv = [a.replace("{tmp}", str(tmp_path / "in")) for a in argv]
    if argv[0] == "calibrate":
        argv += ["--out", str(tmp_path / "out")]
    code, line = _one_line_error(argv, capsys)
    assert code == 2
    assert line.startswith(f"scanner: error: {flag}: "), line
    assert expected in line, line
    # No key path of the configuration ("views.count", "eye_to_hand.held_out", "board:").
    assert not re.search(r"\b[a-z_]+\.[a-z_]+:|^scanner: error: --[a-z-]+: [a-z_]+: ", line), line
    assert not (tmp_path / "out").exists()


def test_bad_formats_name_the_option(tmp_path, capsys):
    code, line = _one_line_error(["reconstruct", str(tmp_path), "--formats", "ply,xyz"], capsys)
    assert code == 2
    assert line.startswith("scanner reconstruct: error: argument --formats: "), line
    assert "'xyz'" in line and "ply, obj, stl" in line and "processing." not in line


def test_usage_error_is_one_line_naming_the_flag():
    r = subprocess.run(
        [sys.executable, "-m", "scanner", "scan", "--size", "-1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2
    assert r.stdout == ""
    assert r.stderr.splitlines() == [
        "scanner scan: error: argument --size: expected a positive length, got '-1' "
        "(see scanner scan --help)"
    ]


@pytest.mark.parametrize(
    "argv, needle",
    [
        ([], "scanner: error: the following arguments are required: COMMAND"),
        (["frobnicate"], "scanner: error: argument COMMAND: invalid choice: 'frobnicate'"),
        (["scan", "--bogus"], "scanner scan: error: unrecognized arguments: --bogus"),
        (["scan", "--views", "many"], "scanner scan: error: argument --views: invalid int"),
        (["calibrate", "--board-spacing", "nan"], "scanner calibrate: error: argument "),
        (["reconstruct"], "scanner reconstruct: error: the following arguments are required"),
        (["export", "c.yaml", "--out", "o"], "required: --format"),
        (["reconstruct", ".", "--workers", "0"], "argument --workers: expected 1 to "),
    ],
)
def test_usage_errors_are_one_line_with_where_to_look(argv, needle, capsys):
    code, line = _one_line_error(argv, capsys)
    assert code == 2
    assert needle in line, line
    prog = line.split(": error:")[0]
    assert line.endswith(f"(see {prog} --help)"), line
