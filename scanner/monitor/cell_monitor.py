"""The cell monitor beside a scan: every frame of the static stereo rig goes through the
intrusion detector and the end-effector tracker; an intrusion stops the arm at the next point of
its (checked) trajectory, no capture is taken while the cell is not clear, and the scan goes on
by itself once the cell has been clear for `clear_time_s`.

Fail safe: a monitor that raises, or that falls more than `max_lag_s` behind the video (the
frames it has not processed yet, counted as a camera's queue would hold them), stops the arm:
the motion is not executed and the scan ends as interrupted (resumable).

Times are on the video's simulated clock (s from the start of the watch).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from robots.models.camera_tool import tool_visual_boxes
from robots.simulation.static_camera import StaticCameraConfig
from scanner.monitor.detector import Detection, IntrusionDetector, MonitorConfig
from scanner.monitor.ee_tracker import EndEffectorTracker, TrackerConfig
from scanner.monitor.stereo_point import StereoRig

log = logging.getLogger("scanner.monitor")


@dataclass(frozen=True)
class MonitorSettings:
    """`monitor:` in a scan configuration (SI units).

    camera: the static stereo rig (its pose from eye-to-hand calibration or set here);
    detection / tracking: the detector's and tracker's settings (`detection.fps` is the frame
    rate); intruder_start_s: simulation only, forearms reaching into the cell at these times;
    capture_dwell_s: the cell is watched this long with the arm still before each capture;
    max_lag_s: the monitor may fall this far behind the video before it stops the arm;
    max_wait_s: an intrusion lasting longer than this ends the scan (interrupted, resumable).
    """

    enabled: bool = False
    camera: StaticCameraConfig = field(default_factory=StaticCameraConfig)
    detection: MonitorConfig = field(default_factory=MonitorConfig)
    tracking: TrackerConfig = field(default_factory=TrackerConfig)
    intruder_start_s: tuple[float, ...] = ()
    capture_dwell_s: float = positive(0.2)
    max_lag_s: float = positive(0.5)
    max_wait_s: float = positive(120.0)
    # Seed of the simulated intruders' paths
    # (robots.simulation.cell_video.intruders.default_intruder_paths).
    intruder_seed: int = integer(0, minimum=0)

    def __post_init__(self) -> None:
        check_fields("monitor", self)
        if self.intruder_start_s and not self.enabled:
            raise ScannerError(
                "monitor.intruder_start_s: simulated intruders need the monitor on "
                "(monitor.enabled, --monitor)"
            )
        bad = [t for t in self.intruder_start_s if not (np.isfinite(t) and t >= 0)]
        if bad:
            raise ScannerError(f"monitor.intruder_start_s: expected times >= 0 s, got {list(bad)}")


@dataclass(frozen=True)
class MonitorEvent:
    t_s: float
    kind: str  # "intrusion", "paused", "clear", "resumed", "ee_disagreement"
    detail: str = ""


class MonitorStoppedError(ScannerError):
    """The monitor failed or fell behind: the arm was stopped before the next motion."""

    exit_code = 1


def volume_in_view(rig: StereoRig, detection: MonitorConfig, margin_px: float = 2.0) -> float:
    """The share of the monitored volume (a 9 x 9 x 9 grid of it) both cameras see: an
    intruder in the rest is never detected."""
    from scanner.monitor.stereo_point import project_W

    lo, hi = np.array(detection.volume_min_m), np.array(detection.volume_max_m)
    grid = np.stack(np.meshgrid(*[np.linspace(0.0, 1.0, 9)] * 3, indexing="ij"), -1)
    points = lo + grid.reshape(-1, 3) * (hi - lo)
    uv_left, uv_right, depth = project_W(rig, points)
    w, h = rig.image_size
    seen = depth > 0
    for uv in (uv_left, uv_right):
        seen &= np.all((uv >= margin_px) & (uv <= np.array([w, h]) - 1 - margin_px), axis=1)
    return float(seen.mean())


# The tracked point: the centre of the camera tool's body, in the flange frame F.
TOOL_CENTRE_F = np.array(tool_visual_boxes()[1].p_FB, float)


class CellMonitor:
    """Watches a CellVideo: `warm_up` once with the arm at rest, then `watch_motion` for every
    trajectory and `watch_rest` while it stands. Keeps every detection, the track, the events
    and the processing time."""

    def __init__(self, video, settings: MonitorSettings, X_WF) -> None:
        self.video = video
        self.settings = settings
        self.X_WF = X_WF
        rig = StereoRig.create(video.stereo, video.X_WS)
        self.volume_in_view = volume_in_view(rig, settings.detection)
        if self.volume_in_view < 1.0:
            log.warning(
                "only %.0f %% of the monitored volume is in the static camera's view: "
                "intruders elsewhere in it are not seen (monitor.camera, monitor.detection)",
                100 * self.volume_in_view,
            )
        self.detector = IntrusionDetector(rig, settings.detection)
        self.tracker = EndEffectorTracker(rig, settings.tracking)
        self.events: list[MonitorEvent] = []
        self.detections: list[Detection] = []
        # (estimate, true tool point, measured joints, arm moving)
        self.track: list[tuple] = []
        self.processing_s = 0.0
        self.frames = 0
        self.lag_s = 0.0
        self.max_lag_seen_s = 0.0
        self._intrusion = False
        self._disagreement = False
        self._object_mask = video.object_mask(0)

    @property
    def fps(self) -> float:
        return self.settings.detection.fps

    def event(self, t_s: float, kind: str, detail: str = "") -> None:
        self.events.append(MonitorEvent(t_s, kind, detail))
        log.warning("monitor t=%.2f s: %s %s", t_s, kind, detail)

    def process(self, frame, moving: bool = False) -> Detection:
        """One frame through the detector and the tracker (`moving`: the arm follows a
        trajectory); raises MonitorStoppedError when the monitor fails or falls behind."""
        start = time.perf_counter()
        try:
            q = frame.q_measured_rad
            # Whole silhouettes: the detector adds its own margin (detection.mask_margin_px).
            mask = self.video.robot_mask(q, 0)
            detection = self.detector.update(
                frame.left, frame.right, mask, frame.t_s, self._object_mask
            )
            X_WF = self.X_WF(q)
            predicted = X_WF[:3, :3] @ TOOL_CENTRE_F + X_WF[:3, 3]
            # The tool's silhouettes at the measured joints: the tracker fits them to the images.
            tool_masks = tuple(self.video.tool_mask(q, side, 0) for side in ("left", "right"))
            estimate = self.tracker.update(
                frame.left, frame.right, frame.t_s, predicted, tool_masks
            )
        except ScannerError:
            raise
        except Exception as e:  # fail safe: whatever broke, the arm must not move unwatched
            raise MonitorStoppedError(f"cell monitor failed ({e}); the robot was stopped") from e
        spent = time.perf_counter() - start
        self.processing_s += spent
        self.frames += 1
        # A camera delivers a frame every 1/fps: work beyond that queues up.
        self.lag_s = max(0.0, self.lag_s + spent - 1.0 / self.fps)
        self.max_lag_seen_s = max(self.max_lag_seen_s, self.lag_s)
        if self.lag_s > self.settings.max_lag_s:
            raise MonitorStoppedError(
                f"cell monitor fell {self.lag_s:.2f} s behind the camera at {self.fps:g} fps "
                f"(limit monitor.max_lag_s {self.settings.max_lag_s:g} s); the robot was stopped"
            )
        X_WF_true = self.X_WF(frame.q_true_rad)
        true_point = X_WF_true[:3, :3] @ TOOL_CENTRE_F + X_WF_true[:3, 3]
        self.track.append((estimate, true_point, q, moving))
        if estimate.disagreement and not self._disagreement:
            self.event(
                frame.t_s,
                "ee_disagreement",
                f"tool seen {1e3 * estimate.error_to_fk_m:.0f} mm from where the robot says",
            )
        self._disagreement = estimate.disagreement
        self.detections.append(detection)
        if detection.intrusion and not self._intrusion:
            where = "" if detection.point_W is None else f" at {np.round(detection.point_W, 2)} m"
            self.event(frame.t_s, "intrusion", f"{detection.area_px} px{where}")
        self._intrusion = detection.intrusion
        return detection

    def warm_up(self, q_measured: np.ndarray) -> None:
        """Frames with the arm still until the background model is ready; refuses a frame
        rate this machine cannot keep up with."""
        frames = self.settings.detection.warmup_frames + 1
        for frame in self.video.frames_at_rest(q_measured, frames / self.fps):
            self.process(frame)
        per_frame = self.processing_s / max(self.frames, 1)
        if per_frame > 1.0 / self.fps:
            raise ScannerError(
                f"monitor.detection.fps: the monitor processes {1.0 / per_frame:.1f} frames/s "
                f"on this machine, below the requested {self.fps:g} fps; lower the rate"
            )

    def watch_motion(self, trajectory) -> float | None:
        """Frames along `trajectory` until an intrusion: its time relative to the trajectory's
        start (the clock then stands at the next frame), or None (the clock at the end)."""
        t0 = self.video.clock_s
        for frame in self.video.frames_along(trajectory, t0):
            if self.process(frame, moving=True).intrusion:
                self.video.clock_s = frame.t_s + 1.0 / self.fps
                return frame.t_s - t0
        return None

    def watch_rest(self, q_measured: np.ndarray, duration_s: float) -> bool:
        """Frames with the arm still for `duration_s`; False as soon as one shows an intrusion
        (the clock then stands after that frame)."""
        for frame in self.video.frames_at_rest(q_measured, duration_s):
            if self.process(frame).intrusion:
                self.video.clock_s = frame.t_s + 1.0 / self.fps
                return False
        return True

    def wait_until_clear(self, q_measured: np.ndarray) -> None:
        """Frames with the arm still until the detector reports the cell clear (no intrusion
        for clear_time_s)."""
        start = self.video.clock_s
        while True:
            (frame,) = list(self.video.frames_at_rest(q_measured, 1.0 / self.fps))
            if self.process(frame).cell_clear:
                self.event(frame.t_s, "clear", f"after {frame.t_s - start:.2f} s")
                return
            if frame.t_s - start > self.settings.max_wait_s:
                raise MonitorStoppedError(
                    f"the cell was not clear for {self.settings.max_wait_s:g} s "
                    "(monitor.max_wait_s); the scan stops here and can be resumed"
                )

    def report(self) -> dict:
        """The monitor's figures for report.json (SI units, accuracy in mm)."""
        return {
            "frames": self.frames,
            "fps": self.fps,
            "fps_processed": self.frames / self.processing_s if self.processing_s else None,
            "max_lag_s": self.max_lag_seen_s,
            "video_s": self.video.clock_s,
            "events": [vars(e) for e in self.events],
        }
