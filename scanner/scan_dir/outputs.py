"""The output rule: no command deletes or overwrites anything it did not write.

An `--out` folder that exists must be empty or hold an earlier result of the same command, and
`--force` replaces such a result and nothing else; an `--out` file that exists is replaced only
with `--force` and only when it is a file of the kind the command writes. An `--out` that
overlaps an input (the same path, inside it, or holding it, links resolved) is refused whatever
it holds: the result would be written over, into or around what the command reads.

`scanner.commands.main` applies the rule to every command's `--out` before the command starts
(`claim_output`, with the command's `OutputKind` from `command_output`); `staged_folder` asks
`replaceable` again before it moves a folder aside, so that a default folder chosen by a command
is never replaced unless it holds a result either."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import yaml

from reconstruction.common.errors import ScannerError

# Files a scan directory's manifest and the results of each command are known by (the commands'
# own modules name them too; these are the names on disk, which never change).
SCAN_MANIFEST = "scan.yaml"
EYE_TO_HAND_MANIFEST = "eye_to_hand_points.yaml"
CALIBRATION_FILE = "calibration.yaml"
EYE_TO_HAND_FILE = "eye_to_hand.yaml"
RECONSTRUCTION_MARKER = "reconstruction.yaml"
INSPECTION_MARKER = "inspection.json"
PLAN_FILE = "plan.json"
PREVIEW_FILES = ("overview.png", "left.png", "right.png")
EXPORT_FILES = (
    "intrinsics.yml",
    "extrinsics.yml",
    "left.yaml",
    "right.yaml",
    "hand_eye_tf.yaml",
)


@dataclass(frozen=True)
class OutputKind:
    """What one command writes. `holds(path)`: whether an existing `path` is an earlier result
    of that command (a folder, or a file when `is_file`). `whole`: a result is replaced as a
    whole (with --force); otherwise the command adds its files beside earlier ones of its kind
    and refuses, file by file, to replace one without --force (export)."""

    what: str
    holds: Callable[[Path], bool]
    is_file: bool = False
    whole: bool = True
    # False: written only into a new or empty folder, --force or not (an imported recording).
    force_replaces: bool = True


def _manifest_kind(folder: Path) -> str | None:
    """'scan' or 'calibration' for a folder with a scan manifest, else None."""
    path = folder / SCAN_MANIFEST
    if not path.is_file():
        return None
    try:
        manifest = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return "unreadable"
    if not isinstance(manifest, dict):
        return "unreadable"
    return "calibration" if manifest.get("kind") == "calibration" else "scan"


def _is_scan(folder: Path) -> bool:
    return _manifest_kind(folder) == "scan"


def _is_calibration(folder: Path) -> bool:
    """A calibration run's folder: live eye-in-hand (a capture store of kind calibration),
    eye-to-hand (its recorded points), or an offline or camera-only solve (results/...)."""
    return (
        _manifest_kind(folder) == "calibration"
        or (folder / EYE_TO_HAND_MANIFEST).is_file()
        or (folder / "results" / CALIBRATION_FILE).is_file()
        or (folder / "results" / EYE_TO_HAND_FILE).is_file()
    )


def _has(marker: str) -> Callable[[Path], bool]:
    return lambda folder: (folder / marker).is_file()


def _only(names: Iterable[str]) -> Callable[[Path], bool]:
    """A folder that holds nothing but these files (and hidden partial folders of a run)."""
    allowed = set(names)
    return lambda folder: all(p.name in allowed or p.name.startswith(".") for p in folder.iterdir())


def _is_calibration_file(path: Path) -> bool:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
    return isinstance(data, dict) and "X_FC" in data


SCAN = OutputKind("a scan directory", _is_scan)
PLAN = OutputKind("a plan", _has(PLAN_FILE))
RECONSTRUCTION = OutputKind("a reconstruction", _has(RECONSTRUCTION_MARKER))
INSPECTION = OutputKind("an inspection", _has(INSPECTION_MARKER))
CALIBRATION = OutputKind("a calibration", _is_calibration)
PREVIEW = OutputKind("a preview", _only(PREVIEW_FILES))
EXPORT = OutputKind("an export", _only(EXPORT_FILES), whole=False)
CALIBRATION_FILE_OUT = OutputKind("a calibration file", _is_calibration_file, is_file=True)
IMPORTED_SCAN = OutputKind("an imported recording", _is_scan, force_replaces=False)

_BY_COMMAND = {
    "calibrate": CALIBRATION,
    "reconstruct": RECONSTRUCTION,
    "merge": RECONSTRUCTION,
    "inspect": INSPECTION,
    "preview": PREVIEW,
    "export": EXPORT,
    "import-calibration": CALIBRATION_FILE_OUT,
    "import-recording": IMPORTED_SCAN,
}


def command_output(args: argparse.Namespace) -> tuple[str, Path, OutputKind] | None:
    """The flag, the path and the kind of what a parsed command line writes to, or None when it
    names no output."""
    out = getattr(args, "out", None)
    if out is None:
        out = getattr(args, "out_file", None)
    if out is None:
        return None
    if args.command == "scan":
        return "--out", out, PLAN if getattr(args, "plan_only", False) else SCAN
    return "--out", out, _BY_COMMAND[args.command]


def input_paths(args: argparse.Namespace, flags: dict[str, str]) -> list[tuple[str, Path]]:
    """Every path a parsed command line reads: each argument that holds a path (or paths),
    other than its output, with its flag (`flags`: argparse dest -> the option or metavar)."""
    found = []
    for name, value in vars(args).items():
        if name in ("out", "out_file"):
            continue
        values = value if isinstance(value, list | tuple) else [value]
        for v in values:
            if isinstance(v, Path):
                found.append((flags.get(name, name), v))
    return found


def _resolved(path: Path) -> Path:
    return Path(path).expanduser().resolve()


def overlap(out: Path, given: Path) -> str | None:
    """How `out` overlaps `given` ('is', 'is inside', 'holds'), or None."""
    a, b = _resolved(out), _resolved(given)
    if a == b:
        return "is"
    if b in a.parents:
        return "is inside"
    if a in b.parents:
        return "holds"
    return None


def replaceable(path: Path, kind: OutputKind, force: bool, flag: str = "--out") -> None:
    """Refuse `path` as the output of `kind` unless it is absent, an empty folder, or (with
    `force`) an earlier result of `kind`. One line naming the flag and what was expected."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return
    if kind.is_file:
        if path.is_dir():
            raise ScannerError(f"{flag} {path}: is a folder, expected a file name")
        if not kind.holds(path):
            raise ScannerError(
                f"{flag} {path}: exists and is not {kind.what}; choose a new file name "
                f"(--force replaces only {kind.what})"
            )
        if not force:
            raise ScannerError(
                f"{flag} {path}: exists already; choose another {flag}, or --force to replace it"
            )
        return
    if not path.is_dir():
        raise ScannerError(f"{flag} {path}: is a file, expected a folder")
    entries = sorted(p.name for p in path.iterdir())
    if not entries:
        return
    shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
    if not kind.force_replaces:
        raise ScannerError(
            f"{flag} {path}: is not empty (it holds {shown}); {kind.what} is written only into "
            "a new or empty folder"
        )
    if not kind.holds(path):
        raise ScannerError(
            f"{flag} {path}: exists and is not {kind.what} (it holds {shown}); choose a new "
            f"or empty folder (--force replaces only {kind.what})"
        )
    if kind.whole and not force:
        raise ScannerError(
            f"{flag} {path}: holds {kind.what} already; choose another {flag}, or --force "
            "to replace it"
        )


def claim_output(
    flag: str, out: Path, kind: OutputKind, force: bool, inputs: list[tuple[str, Path]]
) -> None:
    """The output rule for one command line, before any work: `out` overlaps no input and is
    `replaceable`."""
    for given_flag, given in inputs:
        how = overlap(out, given)
        if how is not None:
            raise ScannerError(
                f"{flag} {out}: {how} {given_flag} {given}; a command never writes over, into "
                "or around what it reads: choose an output outside it"
            )
    replaceable(out, kind, force, flag)
