"""Which reader a recording needs (named, or recognised from its files) and the reading itself:
`read_recording` is the one entry point; every recording it returns has passed `check_recording`.
"""

from __future__ import annotations

from pathlib import Path

from reconstruction.common.errors import ScannerError
from reconstruction.recordings import colmap, idr, plain
from reconstruction.recordings.colmap import KnownDistance
from reconstruction.recordings.recording import Recording, check_recording

FORMATS = (idr.FORMAT, colmap.FORMAT, plain.FORMAT)


def detect_format(source: Path) -> str:
    """The format whose files SOURCE holds; one line naming what was looked for when none or
    several are there."""
    source = Path(source)
    if not source.exists():
        raise ScannerError(f"{source}: no such file or folder")
    found = [
        name
        for name, present in (
            (idr.FORMAT, source.is_dir() and idr.camera_file(source) is not None),
            (colmap.FORMAT, source.is_dir() and colmap.model_folder(source) is not None),
            (plain.FORMAT, plain.recording_file(source) is not None),
        )
        if present
    ]
    if not found:
        raise ScannerError(
            f"{source}: not a recording: expected {' or '.join(idr.CAMERA_FILES)} (idr), a "
            f"COLMAP model in sparse/0/ (colmap) or {plain.FILE_NAME} (plain)"
        )
    if len(found) > 1:
        raise ScannerError(
            f"{source}: holds the files of {' and '.join(found)}; choose one with --format"
        )
    return found[0]


def read_recording(
    source: Path,
    format: str | None = None,
    metres_per_unit: float | None = None,
    known_distance: KnownDistance | None = None,
    masks: Path | None = None,
) -> Recording:
    """The checked recording in SOURCE. format: idr, colmap or plain (None: detected);
    metres_per_unit: the source's unit in metres (idr: default millimetres; colmap: this or
    known_distance is required; plain: the file states unit_m, so it is refused here);
    masks: a folder of masks, one per view in the order of the images' names."""
    fmt = detect_format(source) if format is None else format
    if fmt not in FORMATS:
        raise ScannerError(f"--format: unknown format {fmt!r}; one of {', '.join(FORMATS)}")
    if known_distance is not None and fmt != colmap.FORMAT:
        raise ScannerError(f"--known-distance applies to COLMAP models, not to --format {fmt}")
    if fmt == idr.FORMAT:
        rec = idr.read_idr(source, metres_per_unit, masks)
    elif fmt == colmap.FORMAT:
        rec = colmap.read_colmap(source, metres_per_unit, known_distance, masks)
    else:
        if metres_per_unit is not None:
            raise ScannerError("--scale: the plain form states its unit (unit_m in the file)")
        rec = plain.read_plain(source, masks)
    check_recording(rec)
    return rec
