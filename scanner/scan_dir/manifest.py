"""The scan manifest (scan.yaml): written when a scan starts, read back once as a `SavedScan`.

It holds the object, the whole configuration, the nominal camera model and X_FC the software
used, the robot model, the viewpoints with their IK options, and the status; `CaptureStore`
writes it atomically. A scan directory imported from another system's recording
(`scanner import-recording`) holds instead its `recording:` (format, source, scale, counts),
`sensor: mono` and X_FC; each of its captures carries its own camera and pose.
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
from reconstruction.depth.camera_model import CameraModel
from robots.arms.default import arm_of, is_arm_file
from robots.sensors import sensor_named
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
        "camera": sensor_named(config.sensor).model_to_dict(camera_model),
        "X_FC_nominal": X_FC.tolist(),
        "robot": robot_entry(config.robot),
        "pose_count": len(views),
        "viewpoints": views_to_manifest(views),
        **plan_info,
    }


RECORDING_KEYS = ("format", "source", "metres_per_unit", "camera_poses_given", "masks", "views")


@dataclass(frozen=True)
class RecordingInfo:
    """What an imported recording's manifest says of it (`recording:` in scan.yaml): the
    reader's format, the absolute source path, the metres per source unit applied, whether
    the source gave camera poses (else flange poses and X_FC), whether masks came with it, and
    the number of views (captures 0 .. views-1)."""

    format: str
    source: str
    metres_per_unit: float
    camera_poses_given: bool
    masks: bool
    views: int

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in RECORDING_KEYS}


def recording_info_from_dict(d, where: str) -> RecordingInfo:
    if not isinstance(d, dict) or any(k not in d for k in RECORDING_KEYS):
        raise ScannerError(f"{where}: recording: expected the keys {', '.join(RECORDING_KEYS)}")
    views, unit = d["views"], d["metres_per_unit"]
    if isinstance(views, bool) or not isinstance(views, int) or views < 1:
        raise ScannerError(f"{where}: recording.views: expected a positive count, got {views!r}")
    if isinstance(unit, bool) or not isinstance(unit, int | float) or not unit > 0:
        raise ScannerError(
            f"{where}: recording.metres_per_unit: expected a positive number, got {unit!r}"
        )
    flags = {k: d[k] for k in ("camera_poses_given", "masks")}
    if not all(isinstance(v, bool) for v in flags.values()):
        raise ScannerError(f"{where}: recording: camera_poses_given and masks must be true/false")
    return RecordingInfo(str(d["format"]), str(d["source"]), float(unit), **flags, views=views)


@dataclass(frozen=True, eq=False)
class SavedScan:
    """A scan directory read back: its store, the manifest, and what the manifest says, parsed
    and validated once (configuration, camera model, nominal X_FC, viewpoints).

    An imported recording (`recording` set) planned no viewpoints (`views` empty), has no
    device model (`camera_model` None: each capture holds its camera and X_WC), one pass over
    all its captures, and the default configuration unless its manifest holds a `config:`."""

    store: CaptureStore
    manifest: dict
    config: ScanConfig
    camera_model: CameraModel | None  # the stereo pair's or the RGB-D device's; None: recording
    X_FC_nominal: np.ndarray
    views: tuple[PlannedView, ...]
    hangings: tuple[tuple[int, ...], ...]  # the view indices of each pass
    hanging: int  # the pass the object hangs for now (the last one started)
    # X_WF(q) to use instead of the flange poses stored with the captures (a reconstruction
    # with a calibration that corrects the robot's own errors); None: the stored ones.
    flange_pose: Callable[[np.ndarray], np.ndarray] | None = None
    recording: RecordingInfo | None = None

    @property
    def sensor(self) -> str:
        """stereo or rgbd (the configuration's), or mono for an imported recording."""
        return "mono" if self.recording is not None else self.config.sensor

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


def require_robot_scan(scan: SavedScan, what: str) -> None:
    """Refuse an imported recording where `what` (a command) needs a scan of this product's own
    cell: a device model, viewpoints and joints."""
    if scan.recording is not None:
        raise ScannerError(
            f"{scan.root}: is an imported recording ({scan.recording.format}, sensor mono); "
            f"{what} takes scans made by scanner scan"
        )


def _open_recording(store: CaptureStore, manifest: dict, where: str) -> SavedScan:
    info = recording_info_from_dict(manifest["recording"], where)
    if manifest.get("sensor") != "mono":
        raise ScannerError(f"{where}: sensor: expected 'mono' for a recording")
    object_name = manifest.get("object")
    if not isinstance(object_name, str) or not object_name:
        raise ScannerError(f"{where}: object: expected the recording's name")
    given = manifest.get("config", {})
    if not isinstance(given, dict):
        raise ScannerError(f"{where}: config: expected a mapping of scan settings")
    config = scan_config_from_dict({"object": object_name, **given}, f"{where}:config")
    return SavedScan(
        store,
        manifest,
        config,
        None,
        check_pose(manifest.get("X_FC"), f"{where}:X_FC"),
        (),
        (tuple(range(info.views)),),
        0,
        recording=info,
    )


def open_scan(scan_dir: Path) -> SavedScan:
    """The scan in `scan_dir`; ScannerError naming the file and field when it is not one."""
    store = CaptureStore.open(scan_dir)
    manifest = store.read_manifest()
    where = str(store.manifest_path)
    if "recording" in manifest:
        return _open_recording(store, manifest, where)
    missing = [k for k in ("config", "camera", "X_FC_nominal", "viewpoints") if k not in manifest]
    if missing:
        raise ScannerError(f"{where}: not a scan manifest (missing {', '.join(missing)})")
    views = views_from_manifest(manifest["viewpoints"], where)
    hangings = _hangings(manifest, views, where)
    hanging = manifest.get("hanging", 0)
    if not isinstance(hanging, int) or not 0 <= hanging < len(hangings):
        raise ScannerError(f"{where}: hanging must be a pass number below {len(hangings)}")
    config = scan_config_from_dict(manifest["config"], f"{where}:config")
    return SavedScan(
        store,
        manifest,
        config,
        # The configuration's sensor kind reads its camera-model file.
        sensor_named(config.sensor).model_from_dict(manifest["camera"], f"{where}:camera"),
        check_pose(manifest["X_FC_nominal"], f"{where}:X_FC_nominal"),
        tuple(views),
        hangings,
        hanging,
    )
