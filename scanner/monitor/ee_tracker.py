"""The end effector tracked in the static rig's video and compared with forward kinematics.

Detection: three-frame differencing (|I_t - I_t-1| and |I_t-1 - I_t-2| both above a threshold)
plus morphology, in a window of each raw image around where forward kinematics puts the tool;
the blob nearest the window's centre gives one pixel per image, and the pair is triangulated
with the rig's model. The intersection of the two differences is the blob as it was in the
MIDDLE frame, so a measurement belongs to time t-1, one frame back; the filter is corrected at
that time and its estimate extrapolated to the current frame.

Filtering: OpenCV's Kalman filter with a constant-velocity model in the world (state x, y, z,
vx, vy, vz), white acceleration as process noise, dt from the frame times.

A tool seen persistently (`disagreement_frames` measured frames in a row) farther than
`disagreement_m` from where forward kinematics says it is means a collision or an encoder
offset: the estimate is flagged.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.checks import check_fields, integer, positive
from reconstruction.errors import ScannerError
from scanner.monitor.stereo_point import StereoRig, project_W, triangulate_W
from scanner.units import mm


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the end-effector tracker (SI units; pixels of the raw full-resolution images;
    grey levels 8-bit)."""

    fps: float = positive(15.0)
    diff_threshold: float = positive(15.0)
    # Half size of the square searched around the tool's predicted pixel: the tool's extent in
    # the image plus what an encoder offset or a collision can move it.
    search_window_px: int = integer(60, minimum=8)
    morph_kernel_px: int = integer(5, minimum=1)
    min_blob_px: int = integer(40, minimum=1)
    # Rows of the rectified pair differ by more than this: the two blobs are not one point.
    max_epipolar_px: float = positive(4.0)
    measurement_noise_m: float = positive(0.005)
    # Standard deviation of the white acceleration of the constant-velocity model: a scanning
    # move changes speed by about 1 m/s within half a second.
    accel_noise_mps2: float = positive(2.0)
    initial_velocity_std_mps: float = positive(1.0)
    # Coasting longer than this without a measurement restarts the track at the next one.
    max_gap_s: float = positive(1.0)
    disagreement_m: float = positive(0.03)
    disagreement_frames: int = integer(3, minimum=1)

    def __post_init__(self) -> None:
        check_fields("tracker", self)


@dataclass(frozen=True, eq=False)
class TrackEstimate:
    """The tracker's estimate at frame time t_s: p_W (m) and v_W (m/s) in the world, None
    before the first measurement and after max_gap_s without one (track lost); measured: this
    frame gave a measurement (of the previous frame's time); error_to_fk_m: |p_W - forward
    kinematics| (None without p_W); disagreement: the error exceeded disagreement_m on
    disagreement_frames measured frames in a row."""

    t_s: float
    p_W: np.ndarray | None
    v_W: np.ndarray | None
    measured: bool
    error_to_fk_m: float | None
    disagreement: bool


@dataclass(frozen=True)
class Blob:
    """The moving blob found in one image: centroid (u, v) in raw pixels and its area (px)."""

    centroid_px: tuple[float, float]
    area_px: int


def _odd(n: int) -> int:
    return n if n % 2 else n + 1


def moving_blob(
    frames: Sequence[np.ndarray],
    centre_px: np.ndarray,
    config: TrackerConfig,
    allowed: np.ndarray | None = None,
) -> Blob | None:
    """The blob of three-frame differencing of frames (I_t-2, I_t-1, I_t) in the window around
    centre_px, nearest that centre; None when nothing large enough moved. allowed: optional bool
    mask (full image) the moving pixels must lie in (the tool's rendered silhouette)."""
    h, w = frames[0].shape
    half = config.search_window_px
    cu, cv_ = int(round(centre_px[0])), int(round(centre_px[1]))
    x0, x1 = max(0, cu - half), min(w, cu + half + 1)
    y0, y1 = max(0, cv_ - half), min(h, cv_ + half + 1)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    a, b, c = (f[y0:y1, x0:x1] for f in frames)
    thr = config.diff_threshold
    d1 = cv2.threshold(cv2.absdiff(c, b), thr, 255, cv2.THRESH_BINARY)[1]
    d2 = cv2.threshold(cv2.absdiff(b, a), thr, 255, cv2.THRESH_BINARY)[1]
    moving = cv2.bitwise_and(d1, d2)
    if allowed is not None:
        moving[~allowed[y0:y1, x0:x1]] = 0
    k = _odd(config.morph_kernel_px)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    # Close first: the differences of a uniform tool are its leading and trailing edges, which
    # closing joins into one blob before opening removes the noise.
    moving = cv2.morphologyEx(moving, cv2.MORPH_CLOSE, kernel)
    moving = cv2.morphologyEx(moving, cv2.MORPH_OPEN, kernel)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(moving, connectivity=8)
    best, best_d = None, math.inf
    for i in range(1, n):
        area = int(stats[i, cv2.CC_STAT_AREA])
        if area < config.min_blob_px:
            continue
        u, v = centroids[i, 0] + x0, centroids[i, 1] + y0
        d = math.hypot(u - centre_px[0], v - centre_px[1])
        if d < best_d:
            best, best_d = Blob((float(u), float(v)), area), d
    return best


def _transition(dt: float) -> np.ndarray:
    F = np.eye(6, dtype=np.float32)
    F[:3, 3:] = dt * np.eye(3)
    return F


def _process_noise(dt: float, accel_std: float) -> np.ndarray:
    """Discrete white-acceleration noise of the constant-velocity model (Bar-Shalom, Estimation
    with Applications to Tracking and Navigation, 6.3.2)."""
    q = accel_std**2
    Q = np.zeros((6, 6), np.float32)
    Q[:3, :3] = q * dt**4 / 4 * np.eye(3)
    Q[:3, 3:] = Q[3:, :3] = q * dt**3 / 2 * np.eye(3)
    Q[3:, 3:] = q * dt**2 * np.eye(3)
    return Q


class EndEffectorTracker:
    """Feed every frame in time order. The first measurement comes with the third frame."""

    def __init__(self, rig: StereoRig, config: TrackerConfig | None = None) -> None:
        self.rig = rig
        self.config = config or TrackerConfig()
        c = self.config
        self._kf = cv2.KalmanFilter(6, 3, 0, cv2.CV_32F)
        self._kf.measurementMatrix = np.hstack([np.eye(3), np.zeros((3, 3))]).astype(np.float32)
        self._kf.measurementNoiseCov = (c.measurement_noise_m**2 * np.eye(3)).astype(np.float32)
        self._history: deque = deque(maxlen=3)
        self._t_filter: float | None = None
        self._over = 0

    def _reset(self, p_W: np.ndarray, t_s: float) -> None:
        c = self.config
        self._kf.statePost = np.concatenate([p_W, np.zeros(3)]).astype(np.float32).reshape(6, 1)
        cov = [c.measurement_noise_m**2] * 3 + [c.initial_velocity_std_mps**2] * 3
        self._kf.errorCovPost = np.diag(cov).astype(np.float32)
        self._t_filter = t_s

    def _measure(self) -> np.ndarray | None:
        """The tool's world point at the middle frame's time, from the last three frames."""
        (_, l0, r0, _, _), (_, l1, r1, fk1, mask1), (_, l2, r2, _, _) = self._history
        uv_left, uv_right, depth = project_W(self.rig, fk1)
        if depth[0] <= 0:
            return None
        blob_l = moving_blob((l0, l1, l2), uv_left[0], self.config, mask1)
        blob_r = moving_blob((r0, r1, r2), uv_right[0], self.config)
        if blob_l is None or blob_r is None:
            return None
        tri = triangulate_W(self.rig, np.array(blob_l.centroid_px), np.array(blob_r.centroid_px))
        if tri.epipolar_error_px > self.config.max_epipolar_px or tri.disparity_px <= 0:
            return None
        return tri.p_W

    def update(
        self,
        left: np.ndarray,
        right: np.ndarray,
        t_s: float,
        predicted_W: np.ndarray,
        tool_mask: np.ndarray | None = None,
    ) -> TrackEstimate:
        """One frame: raw grey uint8 left/right images, the frame time (s), the tracked point
        where forward kinematics puts it at the measured joints (3,) in W (the tool's centre as
        the camera sees it, e.g. the centre of the camera tool), and optionally the tool's
        silhouette in the left image (bool) to keep other moving links out of the blob."""
        c = self.config
        predicted_W = np.asarray(predicted_W, float).reshape(3)
        if not np.all(np.isfinite(predicted_W)):
            raise ScannerError("tracker: predicted_W must be three finite numbers (m)")
        if self._history and t_s <= self._history[-1][0]:
            raise ScannerError(
                f"tracker: frame times must increase, got {t_s} after {self._history[-1][0]}"
            )
        if left.shape != right.shape or left.ndim != 2 or left.dtype != np.uint8:
            raise ScannerError("tracker: left and right must be grey uint8 images of one size")
        mask = None if tool_mask is None else np.asarray(tool_mask, bool)
        self._history.append((float(t_s), left.copy(), right.copy(), predicted_W, mask))

        measured = False
        if len(self._history) == 3:
            t_mid = self._history[1][0]
            p_meas = self._measure()
            if p_meas is not None:
                measured = True
                if self._t_filter is None or t_mid - self._t_filter > c.max_gap_s:
                    self._reset(p_meas, t_mid)
                else:
                    dt = t_mid - self._t_filter
                    self._kf.transitionMatrix = _transition(dt)
                    self._kf.processNoiseCov = _process_noise(dt, c.accel_noise_mps2)
                    self._kf.predict()
                    self._kf.correct(p_meas.astype(np.float32).reshape(3, 1))
                    self._t_filter = t_mid
        if self._t_filter is None or t_s - self._t_filter > c.max_gap_s:
            # No track yet, or lost: extrapolating a stale velocity would invent positions.
            return TrackEstimate(t_s, None, None, measured, None, False)
        state = self._kf.statePost.ravel().astype(float)
        v_W = state[3:]
        p_W = state[:3] + v_W * (t_s - self._t_filter)
        error = float(np.linalg.norm(p_W - predicted_W))
        if measured:
            self._over = self._over + 1 if error > c.disagreement_m else 0
        return TrackEstimate(t_s, p_W, v_W, measured, error, self._over >= c.disagreement_frames)


@dataclass(frozen=True)
class TrackingErrors:
    """How well a track followed the true trajectory over the estimates that had a position."""

    rms_position_m: float
    max_position_m: float
    rms_velocity_mps: float
    frames: int

    def lines(self) -> list[str]:
        return [
            f"end-effector position error: RMS {mm(self.rms_position_m):.1f} mm, "
            f"max {mm(self.max_position_m):.1f} mm over {self.frames} frames",
            f"end-effector velocity error: RMS {mm(self.rms_velocity_mps):.1f} mm/s",
        ]


def tracking_errors(
    estimates: Sequence[TrackEstimate], p_true_W: np.ndarray, v_true_W: np.ndarray
) -> TrackingErrors:
    """Errors of `estimates` against the true positions (N, 3) and velocities (N, 3) at the
    same frames; estimates without a position are skipped."""
    p_true_W, v_true_W = np.asarray(p_true_W, float), np.asarray(v_true_W, float)
    if len(p_true_W) != len(estimates) or len(v_true_W) != len(estimates):
        raise ScannerError("tracking_errors: one true position and velocity per estimate")
    keep = [i for i, e in enumerate(estimates) if e.p_W is not None]
    if not keep:
        raise ScannerError("tracking_errors: no estimate has a position yet")
    p = np.array([estimates[i].p_W for i in keep])
    v = np.array([estimates[i].v_W for i in keep])
    e_p = np.linalg.norm(p - p_true_W[keep], axis=1)
    e_v = np.linalg.norm(v - v_true_W[keep], axis=1)
    return TrackingErrors(
        float(np.sqrt(np.mean(e_p**2))),
        float(e_p.max()),
        float(np.sqrt(np.mean(e_v**2))),
        len(keep),
    )
