"""The end effector tracked in the static rig's video and compared with forward kinematics.

Detection, with the tool's silhouettes (whole, undilated) rendered at the MEASURED joints in the
left and right raw images: each silhouette is slid over its image, up to `max_shift_px` each
way, to where its outline best matches the image's edges (correlation of smoothed gradients;
the outline's sign follows the tool's contrast, so a dark tool on a pale wall and a pale one on
a dark wall both match); the shift is refined to sub-pixel by a parabola through the peak. The
tool's point seen is where forward kinematics projects it, moved by that image shift, in each
image; the pair is triangulated with the rig's model. The silhouette only says what to look
for: where the tool is comes from the images, so an encoder offset or a collision shows as a
shift (a rendered flat-shaded tool differences into thin edge fragments, too little to measure).
A match is accepted when the outline's mean grey step at the peak reaches `min_contrast_grey`
(the tool hidden, or out of the picture, gives none). Measurements belong to the current frame.

Without silhouettes: three-frame differencing (|I_t - I_t-1| and |I_t-1 - I_t-2| both above a
threshold) plus morphology, in a window of each raw image around where forward kinematics puts
the tool; the blob nearest the window's centre gives one pixel per image. The intersection of the
two differences is the blob as it was in the MIDDLE frame, so a measurement belongs to time
t-1, one frame back. Coarser (a blob's centroid is not the tool's centre); for textured tools.

Filtering: OpenCV's Kalman filter with a constant-velocity model in the world (state x, y, z,
vx, vy, vz), white acceleration as process noise, dt from the frame times; corrected at the
measurement's time and extrapolated to the current frame.

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

from reconstruction.common.checks import check_fields, integer, positive
from reconstruction.common.errors import ScannerError
from scanner.monitor.stereo_point import StereoRig, project_W, triangulate_W
from scanner.reports.units import mm


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
    # Silhouette matching: how far (px) the tool may lie from its rendered silhouette, i.e. what
    # an encoder offset or a collision can move it (40 px: 5 cm at 0.8 m with f = 640 px).
    max_shift_px: int = integer(40, minimum=1)
    # Gaussian smoothing (px) of both gradients: widens the match's peak for the sub-pixel fit.
    edge_sigma_px: float = positive(1.0)
    # Mean grey step across the outline at the match: rendered tools show 90-150 against the
    # cell; sensor noise alone (2 grey levels) correlates to a few.
    min_contrast_grey: float = positive(20.0)
    # Silhouette matches scatter by ~1.5 mm at 0.8 m (0.2 px); blob centroids by ~5 mm.
    measurement_noise_m: float = positive(0.002)
    blob_measurement_noise_m: float = positive(0.005)
    # Standard deviation of the white acceleration of the constant-velocity model: a scanning
    # move changes speed by about 1 m/s within half a second.
    accel_noise_mps2: float = positive(2.0)
    initial_velocity_std_mps: float = positive(1.0)
    # Coasting longer than this without a measurement restarts the track at the next one.
    max_gap_s: float = positive(1.0)
    # 0.02 rad on joint 1 moves the tool 7-12 mm at the scanning reach; the track of a
    # matched silhouette stays within 3 mm of the truth.
    disagreement_m: float = positive(0.005)
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


@dataclass(frozen=True)
class SilhouetteMatch:
    """Where a silhouette's outline best matches an image: shift_px (du, dv) from the rendered
    silhouette to the image, and the outline's mean grey step there (grey levels; its sign is
    the tool's: negative for a tool darker than its surroundings)."""

    shift_px: tuple[float, float]
    contrast_grey: float


def _smoothed_gradients(image: np.ndarray, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    f = cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma_px)
    # Sobel's 3x3 kernel sums to 8 x the central difference: /8 keeps grey levels per pixel.
    return (
        cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3) / 8.0,
        cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3) / 8.0,
    )


def _replicated(image: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    """image[y0:y1, x0:x1] where the box may reach beyond the image: the border replicated."""
    h, w = image.shape
    cy0, cy1 = min(max(y0, 0), h - 1), max(min(y1, h), 1)
    cx0, cx1 = min(max(x0, 0), w - 1), max(min(x1, w), 1)
    return cv2.copyMakeBorder(
        image[cy0:cy1, cx0:cx1],
        cy0 - y0,
        y1 - cy1,
        cx0 - x0,
        x1 - cx1,
        cv2.BORDER_REPLICATE,
    )


def _parabola_peak(a: float, b: float, c: float) -> float:
    """Offset (-0.5..0.5) of the extremum of the parabola through (-1, a), (0, b), (1, c)."""
    den = a - 2.0 * b + c
    return 0.0 if den == 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


def silhouette_shift(
    image: np.ndarray,
    silhouette: np.ndarray,
    max_shift_px: int,
    edge_sigma_px: float = 1.0,
    min_area_px: int = 1,
) -> SilhouetteMatch | None:
    """The shift (within +-max_shift_px in u and v) that best lays the outline of `silhouette`
    ((H, W) bool, the tool where the model puts it) on the edges of `image` ((H, W) grey):
    the correlation of their smoothed gradients, strongest in either sign. None when the
    silhouette has fewer than `min_area_px` pixels or reaches the image's border."""
    ys, xs = np.nonzero(silhouette)
    h, w = image.shape
    if len(xs) < max(1, min_area_px):
        return None
    if xs.min() == 0 or ys.min() == 0 or xs.max() == w - 1 or ys.max() == h - 1:
        # Cut by the picture's edge: the match would slide along the cut (10 mm off, measured).
        return None
    m = int(max_shift_px)
    pad = int(math.ceil(3 * edge_sigma_px)) + 2
    y0, y1, x0, x1 = ys.min() - pad, ys.max() + pad + 1, xs.min() - pad, xs.max() + pad + 1
    template = _replicated(silhouette.astype(np.float32), y0, y1, x0, x1)
    tgx, tgy = _smoothed_gradients(template, edge_sigma_px)
    total = float((tgx * tgx + tgy * tgy).sum())
    if total <= 0:
        return None
    wy0, wy1, wx0, wx1 = y0 - m, y1 + m, x0 - m, x1 + m
    igx, igy = _smoothed_gradients(_replicated(image, wy0, wy1, wx0, wx1), edge_sigma_px)
    score = cv2.matchTemplate(igx, tgx, cv2.TM_CCORR) + cv2.matchTemplate(igy, tgy, cv2.TM_CCORR)
    magnitude = np.abs(score)
    by, bx = np.unravel_index(int(np.argmax(magnitude)), magnitude.shape)
    du, dv = float(bx - m), float(by - m)
    if 0 < bx < magnitude.shape[1] - 1:
        du += _parabola_peak(*magnitude[by, bx - 1 : bx + 2])
    if 0 < by < magnitude.shape[0] - 1:
        dv += _parabola_peak(*magnitude[by - 1 : by + 2, bx])
    # The template's outline is a unit step: the score over its energy is the image's step.
    return SilhouetteMatch((du, dv), float(score[by, bx]) / total)


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
    """Feed every frame in time order. With the tool's silhouettes the first measurement comes
    with the first frame, without them with the third."""

    def __init__(self, rig: StereoRig, config: TrackerConfig | None = None) -> None:
        self.rig = rig
        self.config = config or TrackerConfig()
        self._kf = cv2.KalmanFilter(6, 3, 0, cv2.CV_32F)
        self._kf.measurementMatrix = np.hstack([np.eye(3), np.zeros((3, 3))]).astype(np.float32)
        self._history: deque = deque(maxlen=3)
        self._t_filter: float | None = None
        self._over = 0

    def _reset(self, p_W: np.ndarray, t_s: float, noise_m: float) -> None:
        c = self.config
        self._kf.statePost = np.concatenate([p_W, np.zeros(3)]).astype(np.float32).reshape(6, 1)
        cov = [noise_m**2] * 3 + [c.initial_velocity_std_mps**2] * 3
        self._kf.errorCovPost = np.diag(cov).astype(np.float32)
        self._t_filter = t_s

    def _triangulated(self, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray | None:
        tri = triangulate_W(self.rig, uv_left, uv_right)
        if tri.epipolar_error_px > self.config.max_epipolar_px or tri.disparity_px <= 0:
            return None
        return tri.p_W

    def _measure_blobs(self) -> np.ndarray | None:
        """The tool's world point at the middle frame's time, from the last three frames."""
        (_, l0, r0, _, _), (_, l1, r1, fk1, _), (_, l2, r2, _, _) = self._history
        uv_left, uv_right, depth = project_W(self.rig, fk1)
        if depth[0] <= 0:
            return None
        blob_l = moving_blob((l0, l1, l2), uv_left[0], self.config)
        blob_r = moving_blob((r0, r1, r2), uv_right[0], self.config)
        if blob_l is None or blob_r is None:
            return None
        return self._triangulated(np.array(blob_l.centroid_px), np.array(blob_r.centroid_px))

    def _measure_silhouettes(self) -> np.ndarray | None:
        """The tool's world point at the current frame's time: forward kinematics' pixel of the
        tracked point moved, in each image, by the shift that lays the tool's silhouette on it."""
        c = self.config
        _, left, right, predicted_W, masks = self._history[-1]
        uv_left, uv_right, depth = project_W(self.rig, predicted_W)
        if depth[0] <= 0:
            return None
        seen = []
        for image, mask in zip((left, right), masks, strict=True):
            match = silhouette_shift(
                image, mask, c.max_shift_px, c.edge_sigma_px, min_area_px=c.min_blob_px
            )
            if match is None or abs(match.contrast_grey) < c.min_contrast_grey:
                return None
            seen.append(np.array(match.shift_px))
        return self._triangulated(uv_left[0] + seen[0], uv_right[0] + seen[1])

    def update(
        self,
        left: np.ndarray,
        right: np.ndarray,
        t_s: float,
        predicted_W: np.ndarray,
        tool_masks: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TrackEstimate:
        """One frame: raw grey uint8 left/right images, the frame time (s), the tracked point
        where forward kinematics puts it at the measured joints (3,) in W (the centre of the
        camera tool's body), and optionally the tool's whole silhouettes (bool, undilated) at
        the measured joints in the left and right images: then the tool is found by matching
        them (see the module docstring), else by three-frame differencing."""
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
        masks = None
        if tool_masks is not None:
            masks = tuple(np.asarray(m, bool) for m in tool_masks)
            if len(masks) != 2 or any(m.shape != left.shape for m in masks):
                raise ScannerError("tracker: tool_masks must be a left and a right image mask")
        self._history.append((float(t_s), left.copy(), right.copy(), predicted_W, masks))

        p_meas, t_meas, noise = None, float(t_s), c.measurement_noise_m
        if masks is not None:
            p_meas = self._measure_silhouettes()
        elif len(self._history) == 3:
            p_meas, t_meas = self._measure_blobs(), self._history[1][0]
            noise = c.blob_measurement_noise_m
        measured = p_meas is not None
        if measured:
            self._kf.measurementNoiseCov = (noise**2 * np.eye(3)).astype(np.float32)
            if self._t_filter is None or t_meas - self._t_filter > c.max_gap_s:
                self._reset(p_meas, t_meas, noise)
            else:
                dt = t_meas - self._t_filter
                self._kf.transitionMatrix = _transition(dt)
                self._kf.processNoiseCov = _process_noise(dt, c.accel_noise_mps2)
                self._kf.predict()
                self._kf.correct(p_meas.astype(np.float32).reshape(3, 1))
                self._t_filter = t_meas
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
