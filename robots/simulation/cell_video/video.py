"""The video of a static stereo camera watching the cell while the arm moves, with intruders.

What a cell monitor receives, simulated: a static stereo rig (StaticCameraConfig: its pose X_WS
and optics) films the cell at a fixed rate; the arm moves along timed trajectories; a person's
forearm may reach into the cell (intruders.py). Everything is rendered from one Drake diagram
built for the video (scene.py); the masks the software knows are rendered by masks.py.
SI units; times in seconds on the video's simulated clock; W = robot base frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.stereo.camera_model import StereoCamera
from robots.arms.arm import Arm
from robots.arms.default import DEFAULT_ARM
from robots.drivers.interfaces import JointTrajectory
from robots.models.objects import ObjectMesh
from robots.models.workcell import WorkcellConfig
from robots.simulation.cell import Simulation
from robots.simulation.cell_video.intruders import DEFAULT_STATIC_CAMERA, IntruderPath
from robots.simulation.cell_video.masks import (
    DEFAULT_MASK_MARGIN_PX,
    check_margin,
    half_camera,
    render_half_mask,
    render_tool_mask,
)
from robots.simulation.cell_video.scene import VideoScene
from robots.simulation.static_camera import StaticCameraConfig
from robots.simulation.stereo_camera import _RenderedCamera
from robots.simulation.truth import Truth

# Industrial machine-vision cameras for safety monitoring run at 10-30 fps; 15 fps gives a
# forearm at 1 m/s 67 mm between frames.
DEFAULT_FPS = 15.0


@dataclass(frozen=True, eq=False)
class CellFrame:
    """One stereo frame of the cell video at `t_s`. The images are raw: lens distortion and
    sensor noise applied, NOT rectified (rectify with `CellVideo.stereo`)."""

    t_s: float
    left: np.ndarray  # (H, W) uint8 grey
    right: np.ndarray  # (H, W) uint8 grey
    q_true_rad: np.ndarray  # (6,) the arm shown
    q_measured_rad: np.ndarray  # (6,) what the controller reports at t_s
    intruders_p_W: tuple[np.ndarray, ...]  # truth: centroids of the intruders present

    @property
    def intruder_present(self) -> bool:
        return bool(self.intruders_p_W)


def _check_time(t_s, name: str) -> float:
    if not (isinstance(t_s, int | float | np.floating) and math.isfinite(t_s)):
        raise ScannerError(f"{name}: expected a finite time in seconds, got {t_s!r}")
    return float(t_s)


def _check_q(q, name: str) -> np.ndarray:
    q = np.asarray(q, float)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise ScannerError(f"{name}: expected 6 finite joint positions (rad)")
    return q


class CellVideo:
    """The static rig's video of the cell, rendered from its own diagram (VideoScene: the scan's
    cell config, object mesh, truth and robot, plus the intruders on `paths`; the scan's
    Simulation is not touched).

    `stereo` is the rig's true StereoCamera, also the software's model (its calibration is
    assumed exact); `X_WS` the true pose of the left optical frame S (the masks use
    `X_WS_software` when given, e.g. an eye-to-hand result); `fps` and `paths` as given;
    `clock_s` the time of the next frame of the video. Sensor noise: the truth's
    `image_noise_std`, seeded by the truth's seed and the frame time (the same frame twice is
    the same image).

    Cost (640x480, software OpenGL as on the build machines): a frame renders only the window
    holding the arm and the forearms over a background rendered once (`roi_rendering`, default
    on; see VideoScene.grey), about 13 ms per camera; noise and distortion ~1 ms. A still scene
    (arm at rest, no forearm moving) is rendered once and only gets new noise (< 1 ms a frame).
    Not thread-safe: one CellVideo per thread.
    """

    def __init__(
        self,
        cell: WorkcellConfig,
        object_mesh: ObjectMesh | None,
        truth: Truth,
        camera: StaticCameraConfig = DEFAULT_STATIC_CAMERA,
        paths: Sequence[IntruderPath] = (),
        arm: Arm = DEFAULT_ARM,
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
        self._scene = VideoScene(cell, object_mesh, truth, arm, self.paths, roi_rendering)
        self._left = _RenderedCamera(self.stereo.left)
        self._right = _RenderedCamera(self.stereo.right)
        self._half = _RenderedCamera(half_camera(self.stereo.left))
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
            sim.workcell.config, sim.object_mesh, sim.truth, camera, paths, sim.robot.arm, fps
        )

    @staticmethod
    def _check_fps(fps) -> float:
        if not (isinstance(fps, int | float) and math.isfinite(fps) and 0 < fps <= 1000):
            raise ScannerError(f"fps: expected frames per second in (0, 1000], got {fps!r}")
        return float(fps)

    # --- frames ---------------------------------------------------------------------------
    def _clean_pair(self, t_s: float, q_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free grey pair; a still scene (same joints, same intruder poses) is reused."""
        poses = [path.X_WI(t_s) for path in self.paths]
        key = q_true.tobytes() + b"".join(b"-" if X is None else X.tobytes() for X in poses)
        if key != self._clean_key:
            self._scene.pose(self._scene.context, q_true, t_s)
            X_WR = self.X_WS @ self.stereo.X_CR
            self._clean = (
                self._scene.grey(self._left, self.X_WS, t_s),
                self._scene.grey(self._right, X_WR, t_s),
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
        """Truth: (H, W) bool, the intruder pixels visible in the raw left image at t_s (the arm
        at its TRUE joints)."""
        t_s = _check_time(t_s, "t_s")
        self._scene.pose(self._scene.context, _check_q(q_true_rad, "q_true_rad"), t_s)
        self._clean_key = None
        labels = self._scene.labels(self._scene.context, self._left, self.X_WS)
        return np.isin(labels, self._scene.intruder_labels)

    # --- masks ----------------------------------------------------------------------------
    def robot_mask(
        self, q_measured_rad: np.ndarray, margin_px: int = DEFAULT_MASK_MARGIN_PX
    ) -> np.ndarray:
        """(H, W) bool on the raw left image: pixels of the robot's links (base to flange) and
        of the camera tool on the flange, rendered with the arm at the MEASURED joints (what the
        software knows; the true arm differs by the encoder offsets), whole silhouettes (also
        where the object or a box hides them), dilated by at least `margin_px`. Rendered at half
        resolution and upscaled (~4 ms); the last mask is cached."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        margin_px = check_margin(margin_px)
        key = (q.tobytes(), margin_px)
        if key != self._mask_key:
            scene = self._scene
            scene.pose(scene.robot_view, q, None)
            self._mask = render_half_mask(
                scene,
                scene.robot_view,
                scene.robot_labels,
                self._half,
                self._X_WS_software,
                margin_px,
                self.stereo.image_size,
            )
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
        (bracket and body, not the links), whole silhouette at the MEASURED joints, seen from
        the software's rig pose, rendered at full resolution in the window holding the tool
        (~5 ms a side), dilated by `margin_px`. What the end-effector tracker fits to the
        images. The two sides of one q are rendered together and cached."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        margin_px = check_margin(margin_px)
        if side not in ("left", "right"):
            raise ScannerError(f"side: expected 'left' or 'right', got {side!r}")
        key = (q.tobytes(), margin_px)
        if key not in self._tool_masks:
            self._scene.pose(self._scene.tool_view, q, None)
            X_WR = self._X_WS_software @ self.stereo.X_CR
            masks = {
                name: render_tool_mask(self._scene, camera, X_WS, margin_px)
                for name, camera, X_WS in (
                    ("left", self._left, self._X_WS_software),
                    ("right", self._right, X_WR),
                )
            }
            # Frames come in order: only the last pose's masks are worth keeping.
            self._tool_masks = {key: masks}
        return self._tool_masks[key][side]

    def object_mask(self, margin_px: int = DEFAULT_MASK_MARGIN_PX) -> np.ndarray:
        """(H, W) bool on the raw left image: the hung object and its rod (all False without
        an object), whole silhouette seen from the software's rig pose, dilated by at least
        `margin_px`, rendered at half resolution as robot_mask; cached per margin."""
        margin_px = check_margin(margin_px)
        if margin_px not in self._object_masks:
            scene = self._scene
            mask = render_half_mask(
                scene,
                scene.object_view,
                scene.object_labels,
                self._half,
                self._X_WS_software,
                margin_px,
                self.stereo.image_size,
            )
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
        """Frames every 1/fps from t0_s (default: the clock; fps default: the video's) while the
        arm follows `trajectory` (MEASURED joints, as the planner sends them; the arm shown is at
        measured + offsets, default the truth's encoder offsets).

        Frames cover [t0, t0 + K/fps) with K = ceil(duration * fps): the final pose is the first
        frame of the next call. Returns an iterator at once and moves `clock_s` to the end of
        the segment (t0 + K/fps) when called, so consecutive calls make one video at a constant
        rate."""
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
        """Frames for `duration_s` with the arm still at q_measured_rad (+ offsets), on the same
        clock as frames_along: an iterator returned at once, `clock_s` moved to the segment's
        end when called."""
        q = _check_q(q_measured_rad, "q_measured_rad")
        duration = _check_time(duration_s, "duration_s")
        if duration < 0:
            raise ScannerError(f"duration_s: expected a duration >= 0 s, got {duration_s!r}")
        offsets = self._offsets(offsets_rad)
        times = self._segment(t0_s, fps, duration)
        return (self._frame(float(t_s), q + offsets, q) for t_s in times)
