"""A checked recording written as a scan directory (`scanner.scan/1`, sensor mono) that
`scanner reconstruct` and the other commands read like a scan of this product.

The folder is written under a hidden partial name beside --out and renamed when complete
(`staged_folder`), so a run that fails or is killed half-way leaves nothing that looks like a
scan; --out must be absent or empty, and is never replaced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reconstruction.recordings.recording import (
    RecordedView,
    Recording,
    read_depth_counts,
    read_image_rgb,
    read_mask,
)
from scanner.scan_dir.captures import MANIFEST, Capture, CaptureStore
from scanner.scan_dir.manifest import RecordingInfo
from scanner.scan_dir.outputs import IMPORTED_SCAN, replaceable
from scanner.scan_dir.results_folder import staged_folder


def object_name(rec: Recording) -> str:
    """The recording's name: its folder's (the file's folder for a plain-form file)."""
    source = Path(rec.source)
    return source.name if source.is_dir() else source.parent.name


def recording_info(rec: Recording) -> RecordingInfo:
    return RecordingInfo(
        rec.format,
        str(Path(rec.source).resolve()),
        float(rec.metres_per_unit),
        bool(rec.camera_poses_given),
        rec.has_masks,
        len(rec.views),
    )


def recording_manifest(rec: Recording) -> dict:
    """scan.yaml of an imported recording (the store adds schema and time stamp)."""
    X_FC = np.eye(4) if rec.X_FC is None else rec.X_FC
    return {
        "status": "captured",
        "object": object_name(rec),
        "sensor": "mono",
        "recording": recording_info(rec).to_dict(),
        "X_FC": X_FC.tolist(),
        "pose_count": len(rec.views),
    }


def capture_of(view: RecordedView, count: int) -> Capture:
    """The capture of one view: its image as RGB, its mask and depth read, X_WF the flange
    pose (X_WC itself when the recording gave camera poses), stamped with its index."""
    return Capture(
        pose_index=view.index,
        pose_count=count,
        q_rad=np.zeros(0),
        X_WF=np.array(view.X_WC if view.X_WF is None else view.X_WF),
        stamp_s=float(view.index),
        left=read_image_rgb(view.image_path),
        right=None,
        depth=None if view.depth_path is None else read_depth_counts(view.depth_path),
        depth_scale_m=view.depth_scale_m,
        mask=None if view.mask_path is None else read_mask(view.mask_path),
        camera=view.camera,
        X_WC=np.array(view.X_WC),
    )


def write_recording_scan(rec: Recording, out: Path) -> Path:
    """Write the checked recording `rec` as the scan directory `out` (absent or empty)."""
    out = Path(out)
    replaceable(out, IMPORTED_SCAN, force=False)
    with staged_folder(out, MANIFEST) as staging:
        store = CaptureStore.create(staging, recording_manifest(rec))
        for view in rec.views:
            store.write_capture(capture_of(view, len(rec.views)))
    return out
