"""The output rule, for every command that writes: an existing --out that is not an earlier
result of the same command is refused with or without --force, an --out that overlaps an input is
refused, --force replaces an earlier result of the same kind only, and nothing of the user's is
touched by a refusal. The commands run in-process (`main`): each refusal comes before any work."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from scanner.commands.main import main
from scanner.scan_dir import outputs
from scanner.scan_dir.results_folder import staged_folder


def _inputs(root: Path) -> dict[str, Path]:
    """One file or folder of each kind the commands read (their contents do not matter: the
    rule is applied before anything is read)."""
    scan = root / "scan"
    (scan / "captures" / "0000").mkdir(parents=True)
    (scan / "captures" / "0000" / "left.png").write_bytes(b"png")
    (scan / "scan.yaml").write_text("schema: scanner.scan/1\n")
    other = root / "scan2"
    other.mkdir()
    (other / "scan.yaml").write_text("schema: scanner.scan/1\n")
    folder = root / "opencv"
    folder.mkdir()
    (folder / "intrinsics.yml").write_text("%YAML:1.0\n")
    for name in ("mesh.ply", "cad.stl", "calibration.yaml", "config.yaml"):
        (root / name).write_text("x\n")
    return {
        "scan": scan,
        "scan2": other,
        "folder": folder,
        "mesh": root / "mesh.ply",
        "cad": root / "cad.stl",
        "calibration": root / "calibration.yaml",
        "config": root / "config.yaml",
    }


# Each command that writes: its command line with OUT for --out, and the input whose path an
# overlapping --out is made from.
COMMANDS = {
    "scan": (["scan", "--config", "{config}", "--out", "OUT"], "config"),
    "plan-only": (["scan", "--plan-only", "--config", "{config}", "--out", "OUT"], "config"),
    "reconstruct": (["reconstruct", "{scan}", "--out", "OUT"], "scan"),
    "merge": (["merge", "{scan}", "{scan2}", "--out", "OUT"], "scan"),
    "inspect": (["inspect", "{mesh}", "--reference", "{cad}", "--out", "OUT"], "mesh"),
    "calibrate": (["calibrate", "--config", "{config}", "--out", "OUT"], "config"),
    "calibrate-offline": (["calibrate", "--offline", "{scan}", "--out", "OUT"], "scan"),
    "calibrate-eye-to-hand": (["calibrate", "--eye-to-hand", "--out", "OUT"], None),
    "export": (["export", "{calibration}", "--format", "opencv", "--out", "OUT"], "calibration"),
    "import-calibration": (
        ["import-calibration", "{folder}", "--format", "opencv", "--out", "OUT"],
        "folder",
    ),
    "preview": (["preview", "--out", "OUT"], None),
}


def _argv(name: str, inputs: dict[str, Path], out: Path, force: bool = False) -> list[str]:
    words, _ = COMMANDS[name]
    argv = [str(out) if w == "OUT" else w.format(**inputs) for w in words]
    return argv + (["--force"] if force else [])


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def _refused(argv, capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("scanner: error: --out"), err
    return err


@pytest.mark.parametrize("force", [False, True], ids=["plain", "force"])
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_folder_of_the_users_is_refused_and_kept(name, force, tmp_path, capsys):
    inputs = _inputs(tmp_path)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("my notes\n")
    if name == "import-calibration":
        out = out / "notes.txt"  # a file output: the user's file
    before = _tree(tmp_path)
    err = _refused(_argv(name, inputs, out, force), capsys)
    assert "exists and is not a" in err
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("how", ["equal", "inside", "holding"])
@pytest.mark.parametrize("name", sorted(n for n, (_, i) in COMMANDS.items() if i is not None))
def test_an_output_overlapping_an_input_is_refused(name, how, tmp_path, capsys):
    root = tmp_path / "work"
    inputs = _inputs(root)
    given = inputs[COMMANDS[name][1]]
    out = {"equal": given, "inside": given / "sub", "holding": root}[how]
    targets = [out]
    if out.is_dir():  # a link to the same place is the same place
        targets.append(tmp_path / "link")
        targets[-1].symlink_to(out, target_is_directory=True)
    before = _tree(root)
    for target in targets:
        err = _refused(_argv(name, inputs, target, force=True), capsys)
        assert {"equal": " is ", "inside": " is inside ", "holding": " holds "}[how] in err
    assert _tree(root) == before


def test_reconstruct_into_the_scans_captures_keeps_them(tmp_path, capsys):
    inputs = _inputs(tmp_path)
    captures = inputs["scan"] / "captures"
    err = _refused(["reconstruct", str(inputs["scan"]), "--out", str(captures)], capsys)
    assert "is inside SCAN_DIR" in err
    assert (captures / "0000" / "left.png").read_bytes() == b"png"


@pytest.mark.parametrize(
    ("kind", "marker"),
    [
        (outputs.RECONSTRUCTION, "reconstruction.yaml"),
        (outputs.INSPECTION, "inspection.json"),
        (outputs.PLAN, "plan.json"),
        (outputs.CALIBRATION, "results/calibration.yaml"),
        (outputs.CALIBRATION, "results/eye_to_hand.yaml"),
        (outputs.CALIBRATION, "eye_to_hand_points.yaml"),
        (outputs.PREVIEW, "overview.png"),
    ],
)
def test_an_earlier_result_needs_force_and_nothing_else_does(kind, marker, tmp_path):
    earlier = tmp_path / "earlier"
    (earlier / marker).parent.mkdir(parents=True, exist_ok=True)
    (earlier / marker).write_text("x\n")
    with pytest.raises(outputs.ScannerError, match="already; choose another --out, or --force"):
        outputs.replaceable(earlier, kind, force=False)
    outputs.replaceable(earlier, kind, force=True)
    empty = tmp_path / "empty"
    empty.mkdir()
    outputs.replaceable(empty, kind, force=False)
    outputs.replaceable(tmp_path / "new", kind, force=False)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(outputs.ScannerError, match="is a file, expected a folder"):
        outputs.replaceable(tmp_path / "a_file", kind, force=True)


def test_scan_and_calibration_directories_are_told_apart(tmp_path):
    scan, calib = tmp_path / "scan", tmp_path / "calib"
    for folder, manifest in ((scan, {"schema": "s"}), (calib, {"kind": "calibration"})):
        folder.mkdir()
        (folder / "scan.yaml").write_text(yaml.safe_dump(manifest))
    outputs.replaceable(scan, outputs.SCAN, force=True)
    outputs.replaceable(calib, outputs.CALIBRATION, force=True)
    with pytest.raises(outputs.ScannerError, match="is not a scan directory "):
        outputs.replaceable(calib, outputs.SCAN, force=True)
    with pytest.raises(outputs.ScannerError, match="is not a calibration "):
        outputs.replaceable(scan, outputs.CALIBRATION, force=True)


def test_export_adds_beside_its_own_files_only(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "intrinsics.yml").write_text("x")
    outputs.replaceable(out, outputs.EXPORT, force=False)  # per file: the command decides
    (out / "mine.txt").write_text("x")
    with pytest.raises(outputs.ScannerError, match="is not an export "):
        outputs.replaceable(out, outputs.EXPORT, force=True)


def test_force_replaces_only_a_calibration_file(tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("notes: 1\n")
    with pytest.raises(outputs.ScannerError, match="is not a calibration file"):
        outputs.replaceable(mine, outputs.CALIBRATION_FILE_OUT, force=True)
    earlier = tmp_path / "calibration.yaml"
    earlier.write_text("X_FC: [[1]]\n")
    with pytest.raises(outputs.ScannerError, match="exists already"):
        outputs.replaceable(earlier, outputs.CALIBRATION_FILE_OUT, force=False)
    outputs.replaceable(earlier, outputs.CALIBRATION_FILE_OUT, force=True)


def test_a_staged_result_never_replaces_a_folder_without_one(tmp_path):
    final = tmp_path / "results"
    final.mkdir()
    (final / "notes.txt").write_text("mine")
    with (
        pytest.raises(outputs.ScannerError, match="holds notes.txt and no result to replace"),
        staged_folder(final, "reconstruction.yaml") as staging,
    ):
        (staging / "reconstruction.yaml").write_text("x")
    assert (final / "notes.txt").read_text() == "mine"
    (final / "notes.txt").unlink()
    (final / "reconstruction.yaml").write_text("old")
    with staged_folder(final, "reconstruction.yaml") as staging:
        (staging / "reconstruction.yaml").write_text("new")
    assert (final / "reconstruction.yaml").read_text() == "new"
