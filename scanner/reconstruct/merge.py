"""`scanner merge SCAN_DIR... --out DIR`: one model from several scans of one object (each of
one or more hangings), aligned into the first scan's first hanging and verified."""

from __future__ import annotations

from pathlib import Path

from reconstruction.common.errors import ScannerError
from robots.sensors import sensor_named
from scanner.reconstruct.stages import (
    RECONSTRUCTION_MARKER,
    ReconstructRun,
    load_processing_config,
    run_reconstruct,
)
from scanner.scan_dir.manifest import open_scan, require_robot_scan
from scanner.scan_dir.results_folder import require_replaceable


def run_merge(
    scan_dirs: list[Path],
    out: Path,
    config: Path | None = None,
    force: bool = False,
    progress: bool = False,
) -> ReconstructRun:
    """Checks the scans belong together (distinct scans, one camera model), then reconstructs
    them as one; a merge whose alignment fails verification raises RefusedResultError."""
    if len(scan_dirs) < 2:
        raise ScannerError(
            f"merge needs two or more scan directories, got {' '.join(map(str, scan_dirs))} "
            "(a multi-hanging scan is merged by its own reconstruction: scanner reconstruct)"
        )
    resolved = [Path(d).resolve() for d in scan_dirs]
    twice = sorted({str(d) for d in resolved if resolved.count(d) > 1})
    if twice:
        raise ScannerError(f"{', '.join(twice)}: given more than once; merge distinct scans")
    scans = [open_scan(d) for d in scan_dirs]
    for scan in scans:
        require_robot_scan(scan, "scanner merge")
    first = _camera_of(scans[0])
    for scan in scans[1:]:
        if _camera_of(scan) != first:
            raise ScannerError(
                f"{scan.root}: made with another camera model than {scans[0].root}; merged "
                "scans share one camera and one hand-eye transform"
            )
    require_replaceable(out, RECONSTRUCTION_MARKER, force, "reconstruction")
    processing = None if config is None else load_processing_config(config)
    return run_reconstruct(scans, processing, Path(out), progress=progress)


def _camera_of(scan) -> tuple[str, dict]:
    """The scan's sensor kind and its camera model as a file section (what must agree)."""
    return scan.sensor, sensor_named(scan.sensor).model_to_dict(scan.camera_model)
