"""The cell monitor over a whole scan: one video per hanging (the object hangs anew), one clock,
the simulated intruders, and the report: what the monitor did, and in simulation how it did
against the truth (intrusions detected and how fast, false alarms, captures while someone was in
the cell, end-effector tracking errors)."""

from __future__ import annotations

import math

import numpy as np

from reconstruction.common.errors import ScannerError
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.models.kinematics import Kinematics
from scanner.monitor.cell_monitor import CellMonitor, MonitorSettings
from scanner.monitor.ee_tracker import tracking_errors
from scanner.monitor.guard import MonitoredCamera, MonitoredRobot

# An alarm within this of an intruder's presence belongs to it (its first frames in the volume
# may still be hidden by the arm, its last ones leaving it).
MATCH_WINDOW_S = 0.5


def intruder_paths(settings: MonitorSettings) -> tuple:
    """The simulated intruders of a monitored scan
    (robots.simulation.cell_video.intruders.IntruderPath), drawn from the settings' start times
    and seed, reaching into the configured monitored volume."""
    from robots.simulation.cell_video.intruders import CellVolume, default_intruder_paths

    d = settings.detection
    volume = CellVolume(d.volume_min_m, d.volume_max_m)
    return default_intruder_paths(
        settings.intruder_start_s, settings.intruder_seed, settings.camera, volume
    )


def intruders_truth(settings: MonitorSettings) -> list[dict]:
    """The intruders for truth.yaml (SI units): what only the simulator knows."""
    return [
        {
            "start_s": p.start_s,
            "end_s": p.end_s,
            "entry_m": list(p.entry_m),
            "stop_m": list(p.stop_m),
            "speed_m_s": p.speed_m_s,
            "dwell_s": p.dwell_s,
            "radius_m": p.radius_m,
            "length_m": p.length_m,
        }
        for p in intruder_paths(settings)
    ]


class ScanMonitor:
    def __init__(self, settings: MonitorSettings, arm: Arm = DEFAULT_ARM) -> None:
        self.settings = settings
        self.paths = intruder_paths(settings)
        # The tracker compares the tool it sees with the scanning arm's own kinematics.
        self.kinematics = Kinematics(arm)
        self.monitors: list[CellMonitor] = []
        self.cameras: list[MonitoredCamera] = []
        self.robots: list[MonitoredRobot] = []
        self.checked = False  # intruder times checked against the first tour

    def start(self, world) -> None:
        """A new video for the world's current hanging, warmed up with the arm still."""
        from robots.simulation.cell_video.video import CellVideo

        if world.sim is None:
            raise ScannerError(
                "monitor.enabled: the cell monitor needs the static camera's video, which only "
                "the simulation provides here (no static camera driver is configured)"
            )
        video = CellVideo.from_simulation(
            world.sim, self.settings.camera, self.paths, self.settings.detection.fps
        )
        video.clock_s = self.clock_s
        monitor = CellMonitor(video, self.settings, self.kinematics.X_WF)
        monitor.warm_up(world.robot.joint_positions())
        self.monitors.append(monitor)

    def check_intruders(self, expected_end_s: float) -> None:
        """Refuse intruder times after the expected end of the scan's video (the warm-up, the
        robot's estimated motion and the watched rests before captures)."""
        late = [t for t in self.settings.intruder_start_s if t > expected_end_s]
        if late:
            raise ScannerError(
                f"--intruder: {', '.join(f'{t:g}' for t in late)} s is after the end of the "
                f"scan (about {expected_end_s:.1f} s on the monitor's clock); give times "
                "within it"
            )

    @property
    def clock_s(self) -> float:
        return self.monitors[-1].video.clock_s if self.monitors else 0.0

    def drivers(self, robot, camera, planner):
        monitor = self.monitors[-1]
        watched = MonitoredRobot(robot, monitor, planner)
        shutter = MonitoredCamera(camera, robot, monitor)
        self.robots.append(watched)
        self.cameras.append(shutter)
        return watched, shutter

    def report(self) -> dict:
        frames = sum(m.frames for m in self.monitors)
        processing = sum(m.processing_s for m in self.monitors)
        events = [vars(e) for m in self.monitors for e in m.events]
        out = {
            "fps": self.settings.detection.fps,
            "frames": frames,
            "fps_processed": frames / processing if processing else None,
            "max_lag_s": max((m.max_lag_seen_s for m in self.monitors), default=0.0),
            "video_s": self.clock_s,
            "pauses": sum(r.pauses for r in self.robots),
            "volume_in_view": min((m.volume_in_view for m in self.monitors), default=None),
            "events": events,
        }
        out.update(self._truth_figures(events))
        return out

    def _truth_figures(self, events: list[dict]) -> dict:
        """Against the simulated truth: the intruders the video held, the alarms, captures and
        the tracked tool."""
        alarms = [e["t_s"] for e in events if e["kind"] == "intrusion"]
        # Frames in alarm, not only its onsets: a monitor already in alarm as the intruder's
        # axis reaches the volume (it came within approach_margin_m first) has detected it.
        alarm_frames = [d.t_s for m in self.monitors for d in m.detections if d.intrusion]
        end = self.clock_s
        intrusions, latencies = [], []
        for path in self.paths:
            entered = _first_present(path, end, self.settings.detection.fps)
            if entered is None:
                continue  # the scan ended before this intruder reached the cell
            left = min(path.end_s, end)
            hits = [
                t for t in alarm_frames if entered - MATCH_WINDOW_S <= t <= left + MATCH_WINDOW_S
            ]
            intrusions.append(
                {"start_s": path.start_s, "entered_s": entered, "detected": bool(hits)}
            )
            if hits:
                latencies.append(max(0.0, hits[0] - entered))
        false_alarms = [
            t
            for t in alarms
            if not any(
                p.start_s - MATCH_WINDOW_S <= t <= p.end_s + MATCH_WINDOW_S for p in self.paths
            )
        ]
        captures = [t for c in self.cameras for t in c.capture_times_s]
        during = [t for t in captures if any(p.present(t) for p in self.paths)]
        out = {
            "intrusions": len(intrusions),
            "detected": sum(i["detected"] for i in intrusions),
            "detection_latency_ms_max": 1e3 * max(latencies) if latencies else None,
            "false_alarms": len(false_alarms),
            "captures": len(captures),
            "captures_during_intrusion": len(during),
            "intruders": intrusions,
        }
        out.update(self._tracking())
        return out

    def _tracking(self) -> dict:
        moving = [r for m in self.monitors for r in m.track if r[3]]
        # Frames with a measurement of the tool: the filter coasting while the tool is out
        # of view or hidden is not tracking (the share tracked is reported beside).
        rows = [r for r in moving if r[0].measured]
        if not rows:
            return {"ee_tracked_fraction": 0.0} if moving else {}
        estimates = [r[0] for r in rows]
        p_true = np.array([r[1] for r in rows])
        t = np.array([e.t_s for e in estimates])
        v_true = np.gradient(p_true, t, axis=0) if len(t) > 1 else np.zeros_like(p_true)
        try:
            errors = tracking_errors(estimates, p_true, v_true)
        except ScannerError:
            return {}  # no estimate had a position yet
        return {
            "ee_tracking_rms_mm": 1e3 * errors.rms_position_m,
            "ee_tracking_max_mm": 1e3 * errors.max_position_m,
            "ee_velocity_rms_mm_s": 1e3 * errors.rms_velocity_mps,
            "ee_tracked_frames": errors.frames,
            "ee_tracked_fraction": errors.frames / len(moving),
        }


def _first_present(path, end_s: float, fps: float) -> float | None:
    """The first frame time at which the intruder is in the monitored volume, before end_s."""
    steps = int(math.ceil(max(0.0, min(path.end_s, end_s) - path.start_s) * fps)) + 1
    for k in range(steps):
        t = path.start_s + k / fps
        if t <= end_s and path.present(t):
            return t
    return None
