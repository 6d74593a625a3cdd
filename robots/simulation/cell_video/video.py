"""The video of a static stereo camera watching the cell while the arm moves, with intruders.

What a cell monitor receives, simulated: a static stereo rig (StaticCameraConfig: its pose X_WS
and optics) films the cell at a fixed rate; the arm moves along timed trajectories; a person's
forearm may reach into the cell. Everything is rendered by Drake's VTK renderer from one diagram
built for the video (the scan's cell, object and truth plus the intruders), so the forearm
occludes and is occluded like any other geometry.

Interface (SI units; times in seconds on the video's simulated clock; W = robot base frame):

- `CellVolume(lo_m, hi_m)`: the monitored volume, an axis-aligned box in W.
  `MONITORED_VOLUME` is the default: the largest box around the arm's working space under the
  hung object that both cameras of the default static rig see whole.
- `IntruderPath(start_s, entry_m, stop_m, speed_m_s, dwell_s, radius_m, length_m, volume)`:
  a forearm, a cylinder whose axis points along its motion. At `start_s` its centroid is at
  `entry_m` (the whole cylinder outside `volume`); it moves in a straight line at `speed_m_s`
  to `stop_m` (inside `volume`), stays `dwell_s`, and goes back the same way; at `end_s` it is
  gone. `position_W(t_s)` is the centroid (3,) while it is in the cell's scene
  (start_s <= t_s <= end_s), else None. `present(t_s)`: some of its axis lies inside `volume`
  (what a monitor must flag). `X_WI(t_s)`: its pose (z axis along the motion), or None.
- `default_intruder_paths(start_times_s, seed, camera, volume)`: one path per start time,
  consecutive ones from different sides (the robot's left and right, above, the camera's
  side), at random heights, speeds (0.5-1.0 m/s) and dwells (0.5-1.5 s); each enters and
  leaves from outside the view of both cameras of `camera`, has its front 0.15 m in their view
  when its axis reaches `volume` (a monitor sees it come), and stops fully in view with its hand
  inside `volume`.
- `CellFrame`: `t_s`, the raw grey `left` and `right` images ((H, W) uint8: lens distortion
  and sensor noise applied, NOT rectified: rectify with `CellVideo.stereo`), the arm's true
  and measured joints, and the truth `intruders_p_W` (centroids of the intruders present).
- `CellVideo(cell, object_mesh, truth, camera, paths, robot, fps, X_WS_software,
  roi_rendering)` or `CellVideo.from_simulation(sim, camera, paths, fps)`: its own diagram (the
  scan's cell config, object mesh, truth and robot; the scan's Simulation is not touched).
  `stereo` (the rig's true StereoCamera, also the software's model: its calibration is assumed
  exact), `X_WS` (true pose of the left optical frame S; the masks use `X_WS_software` when
  given, e.g. an eye-to-hand result), `fps`, `clock_s` (time of the next frame of the video),
  `paths`. Sensor noise: the truth's `image_noise_std`, seeded by the truth's seed and the
  frame time (the same frame twice is the same image).
  - `frame(t_s, q_true_rad)`: one frame with the arm at its TRUE joints.
  - `frames_along(trajectory, t0_s=None, fps=None, offsets_rad=None)`: frames every 1/fps
    from t0_s (default: the clock) while the arm follows `trajectory` (MEASURED joints, as the
    planner sends them; the arm shown is at measured + offsets, default the truth's encoder
    offsets). Frames cover [t0, t0 + K/fps) with K = ceil(duration * fps): the final pose is
    the first frame of the next call. `frames_at_rest(q_measured_rad, duration_s, t0_s=None,
    fps=None, offsets_rad=None)`: the arm still. Both return an iterator at once and move
    `clock_s` to the end of their segment (t0 + K/fps) when called, so consecutive calls make
    one video at a constant rate.
  - `robot_mask(q_measured_rad, margin_px)`: (H, W) bool on the raw LEFT image: pixels of the
    robot's links (base to flange) and of the camera tool on the flange, rendered with the arm
    at the MEASURED joints (what the software knows; the true arm differs by the encoder
    offsets), whole silhouettes (also where the object or a box hides them), dilated by at
    least `margin_px`. Rendered at half resolution and upscaled; the last mask is cached.
  - `tool_mask(q_measured_rad, side, margin_px)`: (H, W) bool on the raw `side` ("left" or
    "right") image: the camera tool alone (bracket and body; not the links), whole silhouette
    at the MEASURED joints, rendered at full resolution in the window holding the tool (~5 ms
    a side), dilated by `margin_px`. What the end-effector tracker fits to the images.
  - `object_mask(margin_px)`: the hung object and its rod, same conventions.
  - `intruder_mask(t_s, q_true_rad)`: truth only, the visible intruder pixels.

Cost (640x480, software OpenGL as on the build machines): a frame renders only the window
holding the arm and the forearms over a background rendered once (`roi_rendering`, default on;
whole renders differ from it in ~10 edge pixels), about 13 ms per camera for the default view
against 28 ms for a whole render; the half-resolution label render of `robot_mask` ~4 ms; noise
and distortion ~1 ms. A still scene (arm at rest, no forearm moving) is rendered once and only
gets new noise (< 1 ms a frame). A CellVideo is not thread-safe: one per thread.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from pydrake.geometry import (
    Box,
    ClippingRange,
    ColorRenderCamera,
    Cylinder,
    RenderCameraCore,
    Role,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.sensors import CameraInfo

from reconstruction.common.checks import check_fields, non_negative, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, make_pose, transform_points
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera, project_points
from robots.drivers.interfaces import JointTrajectory
from robots.models.objects import ObjectMesh
from robots.models.rx60 import RX60
from robots.models.workcell import RENDERER_NAME, WorkcellConfig, build_workcell, placed_object
from robots.simulation.cell import Simulation, textured_object
from robots.simulation.static_camera import StaticCameraConfig
from robots.simulation.stereo_camera import (
    FAR_CLIP_M,
    NEAR_CLIP_M,
    _RenderedCamera,
    undistorted_normalised,
)
from robots.simulation.truth import Truth

# Industrial machine-vision cameras for safety monitoring run at 10-30 fps; 15 fps gives a
# forearm at 1 m/s 67 mm between frames.
DEFAULT_FPS = 15.0
# Forearm of an adult: wrist to elbow about 0.27 m, plus the hand; 90 mm across (anthropometric
# tables, 50th percentile male, rounded up).
FOREARM_RADIUS_M = 0.045
FOREARM_LENGTH_M = 0.35
# A blue work-jacket sleeve: mid grey to a grey camera (0.42 lit head-on), apart from the pale
# walls and radiator (0.8-0.9) and the dark table top. Bare skin was the grey of the wall behind
# and left most of the forearm invisible to a grey camera.
FOREARM_RGBA = (0.2, 0.4, 0.8, 1.0)
# Where an absent intruder waits: far beyond the renderer's far clip (5 m), so never drawn.
PARKED_p_W = (0.0, 0.0, -100.0)
DEFAULT_MASK_MARGIN_PX = 8
DEFAULT_STATIC_CAMERA = StaticCameraConfig()


@dataclass(frozen=True)
class CellVolume:
    """An axis-aligned box in W (m): lower and upper corners."""

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


# The space a person must not reach into while the arm scans: the largest box the default
# static rig (StaticCameraConfig) sees whole, both cameras, 2 px inside their images with the
# lens distortion, that holds the arm's working space under the hung object (x -0.15..0.45,
# y -0.22..0.18, z 0.25..0.68 m) and stays over the table (x >= -0.5 m, robots/workcell.py).
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
    """A forearm reaching into the cell and back (see the module docstring)."""

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
        """Centroid (3,) in W while the forearm is in the scene, else None."""
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
        """Whether some of the forearm's axis is inside the monitored volume at t_s."""
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
    """One forearm path per start time (see the module docstring); reproducible per seed."""
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


@dataclass(frozen=True, eq=False)
class CellFrame:
    """One stereo frame of the cell video (images raw: distorted, noisy, not rectified)."""

    t_s: float
    left: np.ndarray  # (H, W) uint8 grey
    right: np.ndarray  # (H, W) uint8 grey
    q_true_rad: np.ndarray  # (6,) the arm shown
    q_measured_rad: np.ndarray  # (6,) what the controller reports at t_s
    intruders_p_W: tuple[np.ndarray, ...]  # truth: centroids of the intruders present

    @property
    def intruder_present(self) -> bool:
        return bool(self.intruders_p_W)


class _Intruders:
    """A build_workcell extra: one free body per path, a visual-only cylinder each."""

    def __init__(self, paths: Sequence[IntruderPath]) -> None:
        self.paths = tuple(paths)
        self.bodies: list = []

    def __call__(self, plant: MultibodyPlant, robot_instance) -> None:
        for i, path in enumerate(self.paths):
            instance = plant.AddModelInstance(f"intruder_{i}")
            inertia = SpatialInertia.SolidCylinderWithMass(
                1.5, path.radius_m, path.length_m, [0.0, 0.0, 1.0]
            )
            body = plant.AddRigidBody(f"intruder_{i}", instance, inertia)
            plant.RegisterVisualGeometry(
                body,
                RigidTransform(),
                Cylinder(path.radius_m, path.length_m),
                f"intruder_{i}_visual",
                np.array(FOREARM_RGBA),
            )
            self.bodies.append(body)


def _half_camera(cam: PinholeCamera) -> PinholeCamera:
    """The same lens on a half-resolution sensor (pixel centres at integers, as OpenCV's)."""
    K = cam.K.copy()
    K[:2, :2] /= 2
    K[:2, 2] = (K[:2, 2] + 0.5) / 2 - 0.5
    return PinholeCamera(K, cam.distortion, cam.width // 2, cam.height // 2)


def _check_time(t_s, name: str) -> float:
    if not (isinstance(t_s, int | float | np.floating) and math.isfinite(t_s)):
        raise ScannerError(f"{name}: expected a finite time in seconds, got {t_s!r}")
    return float(t_s)


def _check_q(q, name: str) -> np.ndarray:
    q = np.asarray(q, float)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise ScannerError(f"{name}: expected 6 finite joint positions (rad)")
    return q


def _check_margin(margin_px) -> int:
    if not (isinstance(margin_px, int | np.integer) and 0 <= margin_px <= 200):
        raise ScannerError(f"margin_px: expected an integer in [0, 200], got {margin_px!r}")
    return int(margin_px)


def _dilated(mask: np.ndarray, margin_px: int) -> np.ndarray:
    if margin_px == 0:
        return mask
    size = 2 * margin_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.dilate(mask, kernel)


def _full_size(half: np.ndarray, video: CellVideo) -> np.ndarray:
    """A half-resolution mask on the full sensor grid (each half pixel covers 2x2 full ones)."""
    w, h = video.stereo.image_size
    return cv2.resize(half, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def _is_tool_geometry(cell, gid) -> bool:
    """The camera tool's visual boxes (robots/workcell.py names them camera_tool_visual_i)."""
    return "camera_tool_visual" in cell.scene_graph.model_inspector().GetName(gid)


_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
# A region of interest this large renders hardly faster than the whole image.
MAX_ROI_FRACTION = 0.6


def bounding_radius_m(shape) -> float | None:
    """Radius of a sphere about the shape's origin holding it; None for other shapes."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Cylinder):
        return math.hypot(shape.radius(), shape.length() / 2)
    if isinstance(shape, Box):
        return 0.5 * math.sqrt(shape.width() ** 2 + shape.depth() ** 2 + shape.height() ** 2)
    return None


def spheres_roi_px(
    p_S: np.ndarray, radius_m: np.ndarray, K: np.ndarray, size: tuple[int, int], margin_px: int
) -> tuple[int, int, int, int] | None:
    """Pixel box (u0, v0, u1, v1), ends exclusive, of a pinhole image (K, size = (w, h)) that
    holds the images of spheres (centres p_S (N, 3) in the camera frame, radii (N,)) and the
    principal point (Drake's renderer wants it inside every image); None when a sphere reaches
    the camera's plane. The image of a sphere lies within that of its bounding cube."""
    w, h = size
    cx, cy = K[0, 2], K[1, 2]
    lo = np.array([math.floor(cx), math.floor(cy)], float)
    hi = lo + 1
    if len(p_S):
        if np.any(p_S[:, 2] - radius_m < NEAR_CLIP_M):
            return None
        corners = p_S[:, None, :] + radius_m[:, None, None] * _CUBE[None]
        uv = corners[..., :2] / corners[..., 2:3] * [K[0, 0], K[1, 1]] + [cx, cy]
        lo = np.minimum(lo, uv.reshape(-1, 2).min(axis=0))
        hi = np.maximum(hi, uv.reshape(-1, 2).max(axis=0))
    u0, v0 = (max(0, math.floor(x) - margin_px) for x in lo)
    u1, v1 = min(w, math.ceil(hi[0]) + margin_px + 1), min(h, math.ceil(hi[1]) + margin_px + 1)
    return u0, v0, u1, v1


def _roi_camera(K: np.ndarray, roi: tuple[int, int, int, int]) -> ColorRenderCamera:
    """The render camera of a sub-window of a pinhole image (same rays: the principal point
    shifts; +0.5 for Drake's pixel-centre convention, as in robots/sim_camera.py)."""
    u0, v0, u1, v1 = roi
    info = CameraInfo(u1 - u0, v1 - v0, K[0, 0], K[1, 1], K[0, 2] + 0.5 - u0, K[1, 2] + 0.5 - v0)
    core = RenderCameraCore(
        RENDERER_NAME, info, ClippingRange(NEAR_CLIP_M, FAR_CLIP_M), RigidTransform()
    )
    return ColorRenderCamera(core, False)


class CellVideo:
    """The static rig's video of the cell (see the module docstring)."""

    def __init__(
        self,
        cell: WorkcellConfig,
        object_mesh: ObjectMesh | None,
        truth: Truth,
        camera: StaticCameraConfig = DEFAULT_STATIC_CAMERA,
        paths: Sequence[IntruderPath] = (),
        robot: RX60 = RX60(),
        fps: float = DEFAULT_FPS,
        X_WS_software: np.ndarray | None = None,
        roi_rendering: bool = True,
    ) -> None:
        self.fps = self._check_fps(fps)
        self.clock_s = 0.0
        self.paths = tuple(paths)
        if not all(isinstance(p, IntruderPath) for p in self.paths):
            raise ScannerError("paths: expected IntruderPath records")
        self._truth = truth
        self._camera = camera
        self.stereo: StereoCamera = camera.stereo_camera()
        self.X_WS = np.array(camera.X_WS, float)
        self.X_WS.setflags(write=False)
        self._X_WS_software = self.X_WS if X_WS_software is None else np.array(X_WS_software)
        self._intruders = _Intruders(self.paths)
        obj = None
        if object_mesh is not None:
            obj = placed_object(
                textured_object(object_mesh, truth.seed),
                object_mesh.vertices,
                object_mesh.triangles,
                truth.X_WO[:3, :3],
            )
        self._cell = build_workcell(
            cell,
            obj,
            truth.X_FC,
            truth.stereo.X_CR,
            robot,
            renderer=True,
            extras=(self._intruders,),
            include_object=object_mesh is not None,
            X_WO=truth.X_WO,
        )
        self._left = _RenderedCamera(self.stereo.left)
        self._right = _RenderedCamera(self.stereo.right)
        self._half = _RenderedCamera(_half_camera(self.stereo.left))
        self._scene = self._cell.diagram.CreateDefaultContext()
        plant = self._cell.plant
        robot_bodies = {int(b) for b in plant.GetBodyIndices(self._cell.robot)}
        object_bodies = (
            {int(plant.GetBodyByName("object").index())} if self._cell.has_object else set()
        )
        self._robot_view, self._robot_labels = self._only(robot_bodies)
        inspector = self._cell.scene_graph.model_inspector()
        tool = [gid for gid, _ in self._geometries() if _is_tool_geometry(self._cell, gid)]
        self._tool_view = self._only_geometries(set(tool))
        self._tool_spheres = [(gid, bounding_radius_m(inspector.GetShape(gid))) for gid in tool]
        self._object_view, self._object_labels = self._only(object_bodies)
        intruder_bodies = {int(b.index()) for b in self._intruders.bodies}
        self._intruder_labels = self._labels_of(intruder_bodies)
        # Only the arm and the forearms move: a frame renders the window holding them over a
        # background rendered once without them (half the time of two whole renders).
        moving = robot_bodies | intruder_bodies
        static = {body for _, body in self._geometries()} - moving
        self._background_view, _ = self._only(static)
        self._backgrounds: dict[int, np.ndarray] = {}
        inspector = self._cell.scene_graph.model_inspector()
        self._moving = [
            (gid, body, bounding_radius_m(inspector.GetShape(gid)))
            for gid, body in self._geometries()
            if body in moving
        ]
        self._roi_rendering = roi_rendering and all(r is not None for *_, r in self._moving)
        self._intruder_body_path = {
            int(b.index()): path for b, path in zip(self._intruders.bodies, self.paths, strict=True)
        }
        self._clean_key: bytes | None = None
        self._clean: tuple[np.ndarray, np.ndarray] | None = None
        self._mask_key: tuple | None = None
        self._mask: np.ndarray | None = None
        self._tool_masks: dict[tuple, np.ndarray] = {}
        self._object_masks: dict[int, np.ndarray] = {}
        self._bank: np.ndarray | None = None

    @classmethod
    def from_simulation(
        cls,
        sim: Simulation,
        camera: StaticCameraConfig = DEFAULT_STATIC_CAMERA,
        paths: Sequence[IntruderPath] = (),
        fps: float = DEFAULT_FPS,
    ) -> CellVideo:
        """The video of the world a scan runs in (its cell, object, errors and robot)."""
        return cls(
            sim.workcell.config, sim.object_mesh, sim.truth, camera, paths, sim.robot.robot, fps
        )

    # --- construction helpers -------------------------------------------------------------
    @staticmethod
    def _check_fps(fps) -> float:
        if not (isinstance(fps, int | float) and math.isfinite(fps) and 0 < fps <= 1000):
            raise ScannerError(f"fps: expected frames per second in (0, 1000], got {fps!r}")
        return float(fps)

    def _geometries(self) -> list[tuple[object, int]]:
        """(geometry id, body index) of every geometry with a perception role."""
        plant, inspector = self._cell.plant, self._cell.scene_graph.model_inspector()
        out = []
        for gid in inspector.GetAllGeometryIds(Role.kPerception):
            body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
            out.append((gid, -1 if body is None else int(body.index())))
        return out

    def _labels_of(self, bodies: set[int]) -> np.ndarray:
        inspector = self._cell.scene_graph.model_inspector()
        labels = {
            int(inspector.GetPerceptionProperties(gid).GetProperty("label", "id"))
            for gid, body in self._geometries()
            if body in bodies
        }
        return np.array(sorted(labels), np.int32)

    def _only(self, bodies: set[int]):
        """A context in which only the geometries of `bodies` are seen, and their labels."""
        keep = {gid for gid, body in self._geometries() if body in bodies}
        return self._only_geometries(keep), self._labels_of(bodies)

    def _only_geometries(self, keep: set):
        """A context in which only the geometries with ids in `keep` are seen."""
        context = self._cell.diagram.CreateDefaultContext()
        sg = self._cell.scene_graph
        sg_context = sg.GetMyMutableContextFromRoot(context)
        source = self._cell.plant.get_source_id()
        for gid, _ in self._geometries():
            if gid not in keep:
                sg.RemoveRole(sg_context, source, gid, Role.kPerception)
        return context

    # --- rendering ------------------------------------------------------------------------
    def _pose(self, context, q_true: np.ndarray, t_s: float | None) -> None:
        plant = self._cell.plant
        plant_context = plant.GetMyContextFromRoot(context)
        plant.SetPositions(plant_context, self._cell.robot, q_true)
        for path, body in zip(self.paths, self._intruders.bodies, strict=True):
            X = None if t_s is None else path.X_WI(t_s)
            pose = RigidTransform(np.array(PARKED_p_W)) if X is None else RigidTransform(X)
            plant.SetFreeBodyPose(plant_context, body, pose)

    def _query(self, context):
        sg = self._cell.scene_graph
        return sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(context))

    def _render_grey(self, context, camera, X_WS: np.ndarray) -> np.ndarray:
        sg = self._cell.scene_graph
        image = self._query(context).RenderColorImage(
            camera, sg.world_frame_id(), RigidTransform(X_WS)
        )
        return cv2.cvtColor(np.asarray(image.data), cv2.COLOR_RGBA2GRAY)

    def _roi(self, camera: _RenderedCamera, X_WS: np.ndarray, t_s: float):
        """The render-grid window holding the moving geometry seen from X_WS, or None."""
        query = self._query(self._scene)
        X_SW = invert(X_WS)
        centres, radii = [], []
        for gid, body, radius in self._moving:
            path = self._intruder_body_path.get(body)
            if path is not None and path.position_W(t_s) is None:
                continue
            centres.append(query.GetPoseInWorld(gid).translation())
            radii.append(radius)
        p_S = transform_points(X_SW, np.array(centres).reshape(-1, 3))
        K, size = camera.maps.K_render, camera.maps.render_size
        roi = spheres_roi_px(p_S, np.array(radii), K, size, margin_px=2)
        if roi is None or (roi[2] - roi[0]) * (roi[3] - roi[1]) > MAX_ROI_FRACTION * np.prod(size):
            return None
        return roi

    def _grey(self, camera: _RenderedCamera, X_WS: np.ndarray, t_s: float) -> np.ndarray:
        """The grey image of the posed scene on the sensor grid (distorted, noise-free)."""
        roi = self._roi(camera, X_WS, t_s) if self._roi_rendering else None
        if roi is None:
            return camera.distort(self._render_grey(self._scene, camera.color, X_WS))
        key = id(camera)
        if key not in self._backgrounds:
            self._backgrounds[key] = self._render_grey(self._background_view, camera.color, X_WS)
        grey = self._backgrounds[key].copy()
        u0, v0, u1, v1 = roi
        K = camera.maps.K_render
        grey[v0:v1, u0:u1] = self._render_grey(self._scene, _roi_camera(K, roi), X_WS)
        return camera.distort(grey)

    def _labels(self, context, camera: _RenderedCamera, X_WS: np.ndarray) -> np.ndarray:
        sg = self._cell.scene_graph
        image = self._query(context).RenderLabelImage(
            camera.color, sg.world_frame_id(), RigidTransform(X_WS)
        )
        return camera.distort(np.asarray(image.data)[..., 0].astype(np.int32), nearest=True)

    def _clean_pair(self, t_s: float, q_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free grey pair; a still scene (same joints, same intruder poses) is reused."""
        poses = [path.X_WI(t_s) for path in self.paths]
        key = q_true.tobytes() + b"".join(b"-" if X is None else X.tobytes() for X in poses)
        if key != self._clean_key:
            self._pose(self._scene, q_true, t_s)
            X_WR = self.X_WS @ self.stereo.X_CR
            self._clean = (
                self._grey(self._left, self.X_WS, t_s),
                self._grey(self._right, X_WR, t_s),
            )
            self._clean_key = key
        return self._clean

    def _noise_bank(self) -> np.ndarray:
        """Gaussian sensor noise (grey levels, rounded) for many frames: a frame adds a window
        of it at a random offset. Drawing 2 x 307 k normals per frame took 8 ms, a third of
        the frame budget; a window costs one addition, and each pixel still gets a different
        draw in each frame (the offsets repeat once in ~10^4 frames)."""
        if self._bank is None:
            w, h = self.stereo.image_size
            rng = np.random.default_rng([self._truth.seed, 0xBA4C])
            noise = rng.normal(0.0, self._truth.image_noise_std, (4, h + 64, w + 64))
            self._bank = np.round(noise).astype(np.int16)
        return self._bank

    def _noisy(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self._truth.image_noise_std <= 0:
            return image.copy()
        bank = self._noise_bank()
        k, dy, dx = rng.integers(len(bank)), rng.integers(64), rng.integers(64)
        h, w = image.shape
        noise = bank[k, dy : dy + h, dx : dx + w]
        return np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8)

    def _frame(self, t_s: float, q_true: np.ndarray, q_measured: np.ndarray) -> CellFrame:
        left, right = self._clean_pair(t_s, q_true)
        # The noise of a frame depends on its time only: a frame rendered twice is the same.
        t_us = int(round(t_s * 1e6))
        rng = np.random.default_rng([self._truth.seed, 0xCE11, int(t_us < 0), abs(t_us)])
        present = tuple(p.position_W(t_s) for p in self.paths if p.present(t_s))
        return CellFrame(
            t_s,
            self._noisy(left, rng),
            self._noisy(right, rng),
            q_true.copy(),
            q_measured.copy(),
            present,
        )

    def frame(self, t_s: float, q_true_rad: np.ndarray) -> CellFrame:
        """One frame at time t_s with the arm at its TRUE joints (q_measured = q_true - offsets,
        the truth's encoder offsets)."""
        t_s = _check_time(t_s, "t_s")
        q_true = _check_q(q_true_rad, "q_true_rad")
        return self._frame(t_s, q_true, q_true - self._truth.joint_offsets_rad)

    def intruder_mask(self, t_s: float, q_true_rad: np.ndarray) -> np.ndarray:
        """Truth: (H, W) bool, the intruder pixels visible in the raw left image at t_s."""
        t_s = _check_time(t_s, "t_s")
        self._pose(self._scene, _check_q(q_true_rad, "q_true_rad"), t_s)
        self._clean_key = None
        labels = self._labels(self._scene, self._left, self.X_WS)
        return np.isin(labels, self._intruder_labels)

    # --- masks ----------------------------------------------------------------------------
    def _half_mask(self, context, labels: np.ndarray, margin_px: int) -> np.ndarray:
        """A label set's silhouette rendered at half resolution, dilated by >= margin_px and
        brought to the full sensor grid (each half pixel covers 2x2 full ones)."""
        half = np.isin(self._labels(context, self._half, self._X_WS_software), labels)
        return _full_size(_dilated(half.astype(np.uint8), (margin_px + 1) // 2), self)

    def robot_mask(
        self, q_measured_rad: np.ndarray, margin_px: int = DEFAULT_MASK_MARGIN_PX
    ) -> np.ndarray:
        """(H, W) bool on the raw left image: robot and camera tool at the MEASURED joints."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        margin_px = _check_margin(margin_px)
        key = (q.tobytes(), margin_px)
        if key != self._mask_key:
            self._pose(self._robot_view, q, None)
            self._mask = self._half_mask(self._robot_view, self._robot_labels, margin_px)
            self._mask.setflags(write=False)
            self._mask_key = key
        return self._mask

    def tool_mask(
        self,
        q_measured_rad: np.ndarray,
        side: str = "left",
        margin_px: int = DEFAULT_MASK_MARGIN_PX,
    ) -> np.ndarray:
        """(H, W) bool on the raw `side` ("left" or "right") image: the camera tool alone
        (bracket and body, not the links) at the MEASURED joints, dilated by >= margin_px, seen
        from the software's rig pose. The two sides of one q are rendered together and cached."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        margin_px = _check_margin(margin_px)
        if side not in ("left", "right"):
            raise ScannerError(f"side: expected 'left' or 'right', got {side!r}")
        key = (q.tobytes(), margin_px)
        if key not in self._tool_masks:
            self._pose(self._tool_view, q, None)
            X_WR = self._X_WS_software @ self.stereo.X_CR
            masks = {}
            for name, camera, X_WS in (
                ("left", self._left, self._X_WS_software),
                ("right", self._right, X_WR),
            ):
                tool = self._tool_pixels(camera, X_WS)
                mask = _dilated(tool.astype(np.uint8), margin_px).astype(bool)
                mask.setflags(write=False)
                masks[name] = mask
            # Frames come in order: only the last pose's masks are worth keeping.
            self._tool_masks = {key: masks}
        return self._tool_masks[key][side]

    def _tool_pixels(self, camera: _RenderedCamera, X_WS: np.ndarray) -> np.ndarray:
        """The posed tool view's silhouette on the sensor grid at full resolution (the tracker
        fits its outline: half resolution doubled its error), rendered in the window holding
        the tool only (half the time of a whole label render)."""
        query = self._query(self._tool_view)
        centres = [query.GetPoseInWorld(gid).translation() for gid, _ in self._tool_spheres]
        radii = np.array([r for _, r in self._tool_spheres])
        p_S = transform_points(invert(X_WS), np.array(centres))
        K, (w, h) = camera.maps.K_render, camera.maps.render_size
        roi = spheres_roi_px(p_S, radii, K, (w, h), margin_px=2)
        sg = self._cell.scene_graph
        if roi is None:
            labels = self._labels(self._tool_view, camera, X_WS)
        else:
            u0, v0, u1, v1 = roi
            window = query.RenderLabelImage(
                _roi_camera(K, roi), sg.world_frame_id(), RigidTransform(X_WS)
            )
            grid = np.full((h, w), -1, np.int32)
            grid[v0:v1, u0:u1] = np.asarray(window.data)[..., 0]
            labels = camera.distort(grid, nearest=True)
        # Every label is the tool's: nothing else has a perception role in this view.
        return np.isin(labels, self._robot_labels)

    def object_mask(self, margin_px: int = DEFAULT_MASK_MARGIN_PX) -> np.ndarray:
        """(H, W) bool on the raw left image: the hung object and its rod (all False without
        an object)."""
        margin_px = _check_margin(margin_px)
        if margin_px not in self._object_masks:
            mask = self._half_mask(self._object_view, self._object_labels, margin_px)
            mask.setflags(write=False)
            self._object_masks[margin_px] = mask
        return self._object_masks[margin_px]

    # --- the clock ------------------------------------------------------------------------
    def _segment(self, t0_s, fps, duration_s: float) -> np.ndarray:
        """Frame times of a segment of `duration_s` starting at t0_s (default the clock);
        moves the clock to its end."""
        t0 = self.clock_s if t0_s is None else _check_time(t0_s, "t0_s")
        rate = self.fps if fps is None else self._check_fps(fps)
        count = max(0, math.ceil(duration_s * rate - 1e-9))
        self.clock_s = t0 + count / rate
        return t0 + np.arange(count) / rate

    def _offsets(self, offsets_rad) -> np.ndarray:
        if offsets_rad is None:
            return np.asarray(self._truth.joint_offsets_rad, float)
        return _check_q(offsets_rad, "offsets_rad")

    def frames_along(
        self,
        trajectory: JointTrajectory,
        t0_s: float | None = None,
        fps: float | None = None,
        offsets_rad: np.ndarray | None = None,
    ) -> Iterator[CellFrame]:
        """Frames while the arm follows `trajectory` (measured joints) from t0_s."""
        if not isinstance(trajectory, JointTrajectory) or trajectory.positions_rad.shape[1] != 6:
            raise ScannerError("trajectory: expected a JointTrajectory of the 6 joints")
        offsets = self._offsets(offsets_rad)
        times = self._segment(t0_s, fps, trajectory.duration_s)
        t_start = float(times[0]) if len(times) else self.clock_s

        def frames() -> Iterator[CellFrame]:
            q_path = trajectory.positions_rad
            for t_s in times:
                tau = t_s - t_start
                q = np.array([np.interp(tau, trajectory.times_s, q_path[:, j]) for j in range(6)])
                yield self._frame(float(t_s), q + offsets, q)

        return frames()

    def frames_at_rest(
        self,
        q_measured_rad: np.ndarray,
        duration_s: float,
        t0_s: float | None = None,
        fps: float | None = None,
        offsets_rad: np.ndarray | None = None,
    ) -> Iterator[CellFrame]:
        """Frames for `duration_s` with the arm still at q_measured_rad (+ offsets)."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        duration = _check_time(duration_s, "duration_s")
        if duration < 0:
            raise ScannerError(f"duration_s: expected a duration >= 0 s, got {duration_s!r}")
        offsets = self._offsets(offsets_rad)
        times = self._segment(t0_s, fps, duration)
        return (self._frame(float(t_s), q + offsets, q) for t_s in times)
