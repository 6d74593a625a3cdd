"""`scanner import-recording SOURCE --out SCAN_DIR`, the runner (its parser:
scanner/commands/import_recording.py): the recording read and checked whole, then written as a
scan directory; a summary and the reader's notes printed."""

from __future__ import annotations

import argparse


def run_import_recording(args: argparse.Namespace) -> int:
    from reconstruction.recordings.colmap import KnownDistance
    from reconstruction.recordings.formats import read_recording
    from scanner.recordings.scan_writer import write_recording_scan

    known = None if args.known_distance is None else KnownDistance(*args.known_distance)
    rec = read_recording(args.source, args.format, args.scale, known, args.masks)
    out = write_recording_scan(rec, args.out)
    first = rec.views[0].camera
    poses = "camera poses" if rec.camera_poses_given else "flange poses and X_FC"
    print(
        f"import-recording ({rec.format}): {len(rec.views)} views, {first.width}x{first.height} "
        f"px, {rec.metres_per_unit:g} m per unit, {poses}, "
        f"{'with' if rec.has_masks else 'no'} masks"
    )
    for note in rec.notes:
        print(f"note: {note}")
    print(f"scan directory: {out}")
    return 0
