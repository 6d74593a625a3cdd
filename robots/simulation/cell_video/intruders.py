"""Intruders of the cell: the monitored volume and the paths of forearms reaching into it.

Pure geometry in W (robot base frame), SI units, times in seconds on the video's simulated clock:
where a forearm is at each time and whether a monitor must flag it. Adding the forearms to the
rendered scene is robots/simulation/cell_video/scene.py's work.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RotationMatrix

from reconstruction.common.checks import check_fields, non_negative, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, transform_points
from reconstruction.stereo.camera_model import project_points
from robots.simulation.static_camera import StaticCameraConfig
from robots.simulation.stereo_camera import undistorted_normalised

# Forearm of an adult: wrist to elbow about 0.27 m, plus the hand; 90 mm across (anthropometric
# tables, 50th percentile male, rounded up).
FOREARM_RADIUS_M = 0.045
FOREARM_LENGTH_M = 0.35
# The rig MONITORED_VOLUME was fitted to, and the default camera of the default paths and the
# video.
DEFAULT_STATIC_CAMERA = StaticCameraConfig()


@dataclass(frozen=True)
class CellVolume:
    """The monitored volume: an axis-aligned box in W (m), lower and upper corners."""

    lo_m: tuple[float, float, float]
    hi_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lo_m, float), np.asarray(self.hi_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite([lo, hi])):
            raise ScannerError("volume: lo_m and hi_m must be three finite numbers each")
        if np.any(hi <= lo):
            raise ScannerError(f"volume: hi_m {self.hi_m} must exceed lo_m {self.lo_m}")

    def contains(self, p_W: np.ndarray) -> bool:
        p = np.asarray(p_W, float)
        return bool(np.all(p >= self.lo_m) and np.all(p <= self.hi_m))

    def meets_segment(self, a_W: np.ndarray, b_W: np.ndarray) -> bool:
        """Whether the segment a-b has a point inside the box (slab clipping)."""
        a, d = np.asarray(a_W, float), np.asarray(b_W, float) - np.asarray(a_W, float)
        lo_t, hi_t = 0.0, 1.0
        for k in range(3):
            if abs(d[k]) < 1e-12:
                if not self.lo_m[k] <= a[k] <= self.hi_m[k]:
                    return False
                continue
            t1, t2 = (self.lo_m[k] - a[k]) / d[k], (self.hi_m[k] - a[k]) / d[k]
            lo_t, hi_t = max(lo_t, min(t1, t2)), min(hi_t, max(t1, t2))
            if lo_t > hi_t:
                return False
        return True


# The default monitored volume, the space a person must not reach into while the arm scans:
# the largest box around the arm's working space under the hung object that the default static
# rig (StaticCameraConfig) sees whole, both cameras, 2 px inside their images with the lens
# distortion. It holds that working space (x -0.15..0.45, y -0.22..0.18, z 0.25..0.68 m) and
# stays over the table (x >= -0.5 m, robots/models/workcell.py).
# Found by growing boxes face by face against the rig's projection, rounded inward to 1 cm.
# A box beyond the rig's view would count intruders no camera can see.
MONITORED_VOLUME = CellVolume((-0.50, -0.31, 0.19), (0.45, 0.24, 0.76))


def _point3(value, name: str) -> tuple[float, float, float]:
    p = np.asarray(value, float) if np.ndim(value) == 1 else None
    if p is None or p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ScannerError(f"intruder.{name}: expected three finite numbers (m), got {value!r}")
    return tuple(float(v) for v in p)


@dataclass(frozen=True)
class IntruderPath:
    """A forearm reaching into the cell and back: a cylinder (`radius_m`, `length_m`) whose axis
    points along its motion.

    At `start_s` its centroid is at `entry_m` (the whole cylinder outside `volume`); it moves in
    a straight line at `speed_m_s` to `stop_m` (inside `volume`), stays `dwell_s`, and goes back
    the same way; at `end_s` it is gone.
    """

    start_s: float = non_negative()
    entry_m: tuple[float, float, float] = (0.5, 1.2, 0.6)
    stop_m: tuple[float, float, float] = (0.5, 0.3, 0.6)
    speed_m_s: float = positive(0.7)
    dwell_s: float = non_negative(1.0)
    radius_m: float = positive(FOREARM_RADIUS_M)
    length_m: float = positive(FOREARM_LENGTH_M)
    volume: CellVolume = field(default=MONITORED_VOLUME)

    def __post_init__(self) -> None:
        check_fields("intruder", self)
        object.__setattr__(self, "entry_m", _point3(self.entry_m, "entry_m"))
        object.__setattr__(self, "stop_m", _point3(self.stop_m, "stop_m"))
        if self.travel_m < 1e-3:
            raise ScannerError("intruder: entry_m and stop_m must differ")
        tail, tip = self._ends(np.asarray(self.entry_m))
        if self.volume.meets_segment(tail, tip):
            raise ScannerError(
                f"intruder.entry_m: {self.entry_m} puts the forearm inside the monitored "
                "volume; it must enter from outside"
            )
        if not self.volume.contains(self.stop_m):
            raise ScannerError(
                f"intruder.stop_m: {self.stop_m} is outside the monitored volume "
                f"{self.volume.lo_m}..{self.volume.hi_m}"
            )

    @property
    def direction_W(self) -> np.ndarray:
        """Unit vector from entry to stop: the forearm's axis, hand first."""
        d = np.subtract(self.stop_m, self.entry_m)
        return d / np.linalg.norm(d)

    @property
    def travel_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.stop_m, self.entry_m)))

    @property
    def travel_s(self) -> float:
        return self.travel_m / self.speed_m_s

    @property
    def end_s(self) -> float:
        return self.start_s + 2 * self.travel_s + self.dwell_s

    def _ends(self, p_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        half = 0.5 * self.length_m * self.direction_W
        return p_W - half, p_W + half

    def position_W(self, t_s: float) -> np.ndarray | None:
        """Centroid (3,) in W while the forearm is in the cell's scene (start_s <= t_s <=
        end_s), else None."""
        if not (self.start_s <= t_s <= self.end_s):
            return None
        going = t_s - self.start_s
        back = self.end_s - t_s
        s = min(going, back, self.travel_s) * self.speed_m_s
        return np.asarray(self.entry_m) + s * self.direction_W

    def X_WI(self, t_s: float) -> np.ndarray | None:
        """Pose of the forearm frame I (centroid, z along the axis hand first), or None."""
        p = self.position_W(t_s)
        if p is None:
            return None
        R = RotationMatrix.MakeFromOneVector(self.direction_W, 2).matrix()
        return make_pose(R, p)

    def present(self, t_s: float) -> bool:
        """Whether some of the forearm's axis is inside the monitored volume at t_s: what a
        monitor must flag."""
        p = self.position_W(t_s)
        return p is not None and self.volume.meets_segment(*self._ends(p))


# Approach directions of default paths: the robot's right (+y) and left (-y), from above, and
# from the camera's side of the cell (+x); each jittered per path.
_SIDES = {
    "+y": np.array([0.0, -1.0, 0.0]),
    "-y": np.array([0.0, 1.0, 0.0]),
    "above": np.array([0.0, 0.0, -1.0]),
    "+x": np.array([-1.0, 0.0, 0.0]),
}


class _View:
    """Which points both cameras of a static rig see (raw image, with a margin)."""

    def __init__(self, camera: StaticCameraConfig) -> None:
        stereo = camera.stereo_camera()
        X_WS = camera.X_WS
        self._cams = [(stereo.left, invert(X_WS)), (stereo.right, invert(X_WS @ stereo.X_CR))]
        self._position = np.asarray(camera.position_m, float)
        # Beyond the sensor's undistorted extent the distortion polynomial may fold back into
        # the image: points there are out of view whatever project_points says.
        cam = stereo.left
        w, h = cam.width - 1.0, cam.height - 1.0
        s = np.linspace(0.0, 1.0, 17)
        border = np.concatenate(
            [np.stack([s * w, 0 * s], 1), np.stack([s * w, 0 * s + h], 1)]
            + [np.stack([0 * s, s * h], 1), np.stack([0 * s + w, s * h], 1)]
        )
        self._xy_max = np.abs(undistorted_normalised(cam, border)).max(axis=0) * 1.05

    def seen(self, p_W: np.ndarray, margin_px: float) -> np.ndarray:
        """(2, N) bool: each point is in the left (row 0) and right (row 1) raw image,
        `margin_px` inside its borders (a negative margin: or that far outside)."""
        seen = []
        for cam, X_SW in self._cams:
            p_S = transform_points(X_SW, p_W)
            z = p_S[:, 2]
            front = z > 0.05
            xy = p_S[:, :2] / np.where(front, z, 1.0)[:, None]
            unfolded = front & np.all(np.abs(xy) <= self._xy_max, axis=1)
            uv = project_points(cam, np.where(unfolded[:, None], p_S, [[0, 0, 1.0]]))
            m = margin_px
            inside = (
                (uv[:, 0] >= m)
                & (uv[:, 0] <= cam.width - 1 - m)
                & (uv[:, 1] >= m)
                & (uv[:, 1] <= cam.height - 1 - m)
            )
            seen.append(unfolded & inside)
        return np.array(seen)

    def camera_distance_m(self, a_W: np.ndarray, b_W: np.ndarray) -> float:
        """Distance from the rig's centre to the segment a-b."""
        d = b_W - a_W
        t = np.clip(np.dot(self._position - a_W, d) / np.dot(d, d), 0.0, 1.0)
        return float(np.linalg.norm(a_W + t * d - self._position))


def _forearm_surface_W(p_W: np.ndarray, axis_W: np.ndarray, radius: float, length: float):
    """Points on a forearm's surface: 9 rings of 8 along its axis."""
    R = RotationMatrix.MakeFromOneVector(axis_W, 2).matrix()
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring_I = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(8)], 1)
    points = [ring_I + [0.0, 0.0, s] for s in np.linspace(-length / 2, length / 2, 9)]
    return np.concatenate(points) @ R.T + p_W


# A stopped forearm lies 10 px inside both images; an entering one has no surface sample
# within 25 px of either image (the samples are up to ~20 px apart on a near forearm).
_STOP_MARGIN_PX = 10.0
_ENTRY_MARGIN_PX = -25.0
# When its axis reaches the monitored volume, the forearm's front this long is in both images:
# a monitor sees it come (at 1.6 m, 0.15 m of a 90 mm forearm is ~2000 px, above the
# detector's smallest candidate), not a hand appearing out of nowhere inside the volume.
_SEEN_AT_ENTRY_M = 0.15


def _entering_s(volume: CellVolume, entry: np.ndarray, d: np.ndarray, length: float) -> float:
    """How far (m) a forearm starting at centroid `entry` moves along d before its axis meets
    the volume (inf if it never does within 3 m)."""
    for s in np.arange(0.0, 3.0, 0.005):
        c = entry + s * d
        if volume.meets_segment(c - 0.5 * length * d, c + 0.5 * length * d):
            return float(s)
    return math.inf


def _sample_path(
    rng: np.random.Generator,
    side: str,
    start_s: float,
    view: _View,
    volume: CellVolume,
) -> IntruderPath | None:
    """One random path from `side`, or None when this draw does not fit the camera's view."""
    lo, hi = np.asarray(volume.lo_m), np.asarray(volume.hi_m)
    stop = rng.uniform(lo, hi)
    # Away from the table (the forearm would sink into it) and from the robot's base column
    # (it would hide inside the arm's pedestal).
    if stop[2] < 0.15 or np.hypot(stop[0], stop[1]) < 0.25:
        return None
    d = _SIDES[side].copy()
    if side == "above":
        tilt = rng.uniform(0.0, math.radians(30))
        azimuth = rng.uniform(0, 2 * np.pi)
        d = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), -1])
    else:
        yaw = rng.uniform(-math.radians(30), math.radians(30))
        c, s = math.cos(yaw), math.sin(yaw)
        d = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], -math.tan(rng.uniform(0, 0.4))])
    d /= np.linalg.norm(d)
    length, radius = FOREARM_LENGTH_M, FOREARM_RADIUS_M
    # The hand reaches into the volume and stays there: a forearm crossing the whole box would
    # stop with its hand out beyond it.
    if not volume.contains(stop + 0.5 * length * d):
        return None
    if not view.seen(_forearm_surface_W(stop, d, radius, length), _STOP_MARGIN_PX).all():
        return None
    for back_m in np.arange(0.3, 2.5, 0.05):
        entry = stop - back_m * d
        ends = (entry - 0.5 * length * d, entry + 0.5 * length * d)
        if volume.meets_segment(*ends):
            continue
        if view.seen(_forearm_surface_W(entry, d, radius, length), _ENTRY_MARGIN_PX).any():
            continue
        if view.camera_distance_m(entry, stop) < 0.3:
            return None
        tip = entry + (_entering_s(volume, entry, d, length) + 0.5 * length) * d
        front = tip - 0.5 * _SEEN_AT_ENTRY_M * d
        if not view.seen(_forearm_surface_W(front, d, radius, _SEEN_AT_ENTRY_M), 0.0).all():
            return None
        return IntruderPath(
            start_s=float(start_s),
            entry_m=tuple(entry),
            stop_m=tuple(stop),
            speed_m_s=float(rng.uniform(0.5, 1.0)),
            dwell_s=float(rng.uniform(0.5, 1.5)),
            volume=volume,
        )
    return None


def default_intruder_paths(
    start_times_s: Sequence[float],
    seed: int,
    camera: StaticCameraConfig = DEFAULT_STATIC_CAMERA,
    volume: CellVolume = MONITORED_VOLUME,
) -> tuple[IntruderPath, ...]:
    """One forearm path per start time (s); reproducible per seed.

    Consecutive paths come from different sides (the robot's left and right, above, the
    camera's side), at random heights, speeds (0.5-1.0 m/s) and dwells (0.5-1.5 s). Each enters
    and leaves from outside the view of both cameras of `camera`, has its front 0.15 m in their
    view when its axis reaches `volume` (a monitor sees it come), and stops fully in view with
    its hand inside `volume`.
    """
    rng = np.random.default_rng([int(seed), 0x1A7])
    view = _View(camera)
    sides = list(_SIDES)
    first = int(rng.integers(len(sides)))
    paths = []
    for i, start_s in enumerate(start_times_s):
        if not (isinstance(start_s, int | float) and math.isfinite(start_s) and start_s >= 0):
            raise ScannerError(f"start_times_s[{i}]: expected a time >= 0 s, got {start_s!r}")
        path = None
        for attempt in range(2000):
            # Each path's own side first, then the others when that side cannot be seen.
            side = sides[(first + i + attempt // 500) % len(sides)]
            path = _sample_path(rng, side, start_s, view, volume)
            if path is not None:
                break
        if path is None:
            raise ScannerError(
                "default_intruder_paths: the static camera sees too little of the monitored "
                "volume to stop a forearm in its view; aim it at the cell"
            )
        paths.append(path)
    return tuple(paths)
