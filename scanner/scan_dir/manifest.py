"""The scan manifest (scan.yaml): written when a scan starts, read back once as a `SavedScan`.

It holds the object, the whole configuration, the nominal camera model and X_FC the software
used, the robot model, the viewpoints with their IK options, and the status; `CaptureStore`
writes it atomically.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planners.ik import Viewpoint
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose
from reconstruction.depth.camera_model import (
    CameraModel,
    camera_model_from_dict,
    camera_model_to_dict,
)
from robots.arms.default import arm_of, is_arm_file
from scanner.configs.scan import ScanConfig, scan_config_from_dict, scan_config_to_dict
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.views import PlannedView, ViewOption


def views_to_manifest(views: list[PlannedView]) -> list[dict]:
    return [
        {
            "index": v.index,
            "direction": [float(x) for x in v.direction],
            "p_WM": list(v.viewpoint.p_WM),
            "p_WT": list(v.viewpoint.p_WT),
            "roll_rad": v.viewpoint.roll_rad,
            "options": [
                {"roll_rad": o.roll_rad, "q_rad": [float(x) for x in o.q]} for o in v.options
            ],
        }
        for v in views
    ]


def views_from_manifest(items: list[dict], where: str) -> list[PlannedView]:
    try:
        return [
            PlannedView(
                int(d["index"]),
                np.array(d["direction"], float),
                Viewpoint(tuple(d["p_WM"]), tuple(d["p_WT"]), float(d["roll_rad"])),
                tuple(
                    ViewOption(float(o["roll_rad"]), np.array(o["q_rad"], float))
                    for o in d["options"]
                ),
            )
            for d in items
        ]
    except (KeyError, TypeError, ValueError) as e:
        raise ScannerError(f"{where}: malformed viewpoint list ({e})") from None


def robot_entry(robot: str) -> dict:
    """The manifest's record of the arm `robot` names: its name, its joints, the SHA-256 of its
    model text (which model the captures' joints belong to) and, for an arm file, its path.
    Scans written before arms were configurable hold {model: staubli_rx60, urdf_sha256} (the
    same hash of the same URDF); nothing reads this entry back, it documents the scan."""
    arm = arm_of(robot)
    entry = {
        "name": arm.name,
        "joint_names": list(arm.joint_names),
        "model_sha256": hashlib.sha256(arm.model_text.encode()).hexdigest(),
    }
    if is_arm_file(robot):
        entry["arm_file"] = str(Path(robot).resolve())
    return entry


def new_manifest(
    config: ScanConfig,
    camera_model: CameraModel,
    X_FC: np.ndarray,
    views: list[PlannedView],
    plan_info: dict,
) -> dict:
    """The manifest of a new scan (the store adds schema, status and time stamps)."""
    return {
        "object": config.object,
        "config": scan_config_to_dict(config),
        "camera": camera_model_to_dict(camera_model),
        "X_FC_nominal": X_FC.tolist(),
        "robot": robot_entry(config.robot),
        "pose_count": len(views),
        "viewpoints": views_to_manifest(views),
        **plan_info,
    }


@dataclass(frozen=True, eq=False)
class SavedScan:
    """A scan directory read back: its store, the manifest, and what the manifest says, parsed
    and validated once (configuration, camera model, nominal X_FC, viewpoints)."""

    store: CaptureStore
    manifest: dict
    config: ScanConfig
    camera_model: CameraModel  # the stereo pair's or the RGB-D device's
    X_FC_nominal: np.ndarray
    views: tuple[PlannedView, ...]
    hangings: tuple[tuple[int, ...], ...]  # the view indices of each pass
    hanging: int  # the pass the object hangs for now (the last one started)
    # X_WF(q) to use instead of the flange poses stored with the captures (a reconstruction
    # with a calibration that corrects the robot's own errors); None: the stored ones.
    flange_pose: Callable[[np.ndarray], np.ndarray] | None = None

    def X_WF(self, capture) -> np.ndarray:
        """The flange pose of a capture this scan's reconstruction uses."""
        return capture.X_WF if self.flange_pose is None else self.flange_pose(capture.q_rad)

    @property
    def root(self) -> Path:
        return self.store.root

    def hanging_of(self, index: int) -> int:
        return next(p for p, views in enumerate(self.hangings) if index in views)


def _hangings(manifest: dict, views: list[PlannedView], where: str) -> tuple[tuple[int, ...], ...]:
    """The passes' view indices; a scan from before hangings is one pass of every view."""
    passes = manifest.get("hangings")
    if passes is None:
        return (tuple(v.index for v in views),)
    known = {v.index for v in views}
    try:
        out = tuple(tuple(int(i) for i in p) for p in passes)
    except (TypeError, ValueError):
        raise ScannerError(f"{where}: hangings must be lists of view indices") from None
    flat = [i for p in out for i in p]
    if not out or sorted(flat) != sorted(known):
        raise ScannerError(f"{where}: hangings do not partition the viewpoints")
    return out


def open_scan(scan_dir: Path) -> SavedScan:
    """The scan in `scan_dir`; ScannerError naming the file and field when it is not one."""
    store = CaptureStore.open(scan_dir)
    manifest = store.read_manifest()
    where = str(store.manifest_path)
    missing = [k for k in ("config", "camera", "X_FC_nominal", "viewpoints") if k not in manifest]
    if missing:
        raise ScannerError(f"{where}: not a scan manifest (missing {', '.join(missing)})")
    views = views_from_manifest(manifest["viewpoints"], where)
    hangings = _hangings(manifest, views, where)
    hanging = manifest.get("hanging", 0)
    if not isinstance(hanging, int) or not 0 <= hanging < len(hangings):
        raise ScannerError(f"{where}: hanging must be a pass number below {len(hangings)}")
    return SavedScan(
        store,
        manifest,
        scan_config_from_dict(manifest["config"], f"{where}:config"),
        camera_model_from_dict(manifest["camera"], f"{where}:camera"),
        check_pose(manifest["X_FC_nominal"], f"{where}:X_FC_nominal"),
        tuple(views),
        hangings,
        hanging,
    )
