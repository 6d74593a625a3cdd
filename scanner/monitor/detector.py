"""Intrusion detection in the robot cell from a static stereo rig while the robot moves.

Moving-object detection with a static camera: a per-pixel background model (OpenCV's MOG2) and
three-frame differencing (a pixel moves when |I_t - I_t-1| and |I_t-1 - I_t-2| both exceed a
threshold; it catches fast motion the background model is slow to flag). The robot's pixels,
rendered from its geometry at the measured joints, and the hung object's are removed before
anything is decided, and the background model never learns from them. What is left, cleaned by
morphology, is a candidate if its connected component is large enough; it is an intrusion when
the stereo pair puts it inside the monitored volume (a world-frame box, counted with a
protective margin `approach_margin_m` around it), so a moving shadow on the far wall or a person
walking behind the fence does not stop the scan.

All image work runs on a downscaled left image (`downscale`); depth is matched at full
resolution in the rectified pair, and only for candidates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.checks import check_fields, fraction, integer, non_negative, positive
from reconstruction.common.errors import ScannerError
from reconstruction.stereo.rectification import rectify_pair
from robots.simulation.cell_video.intruders import MONITORED_VOLUME
from scanner.monitor.stereo_point import StereoRig, disparity_range, lift_rectified_W


def _check_box(section: str, lo, hi) -> None:
    for name, v in (("volume_min_m", lo), ("volume_max_m", hi)):
        if not (
            isinstance(v, tuple | list)
            and len(v) == 3
            and all(isinstance(c, int | float) and math.isfinite(c) for c in v)
        ):
            raise ScannerError(f"{section}.{name}: expected three finite numbers (m), got {v!r}")
    if not all(a < b for a, b in zip(lo, hi, strict=True)):
        raise ScannerError(
            f"{section}.volume_max_m: expected every coordinate above volume_min_m "
            f"{list(lo)}, got {list(hi)}"
        )


@dataclass(frozen=True)
class MonitorConfig:
    """Settings of the cell monitor. Pixel sizes are in full-resolution pixels of the left
    image; grey levels are 8-bit. The monitored volume is an axis-aligned world box (m); the
    default is the arm's working space under the hung object, all of it in the default rig's
    view (an intruder where no camera sees cannot be detected)."""

    fps: float = positive(15.0)
    # Half resolution averages 4 pixels: sensor noise drops by 2 and the per-frame cost by 4,
    # while a forearm at 2 m still covers hundreds of pixels.
    downscale: int = integer(2, minimum=1, maximum=8)
    min_area_px: float = positive(1200.0)
    diff_threshold: float = positive(20.0)
    # MOG2's squared Mahalanobis distance to call a pixel foreground (OpenCV's default is 16).
    bg_var_threshold: float = positive(25.0)
    bg_history_frames: int = integer(150, minimum=2)
    # Frames before any decision: the background model needs a first estimate of every pixel.
    warmup_frames: int = integer(30, minimum=3)
    # Frames a pixel must have been seen unmasked before the background model judges it: a
    # pixel the robot covered since start-up holds the robot's grey until MOG2 adopts the new
    # mode, after about 0.1 * bg_history_frames frames (its background ratio is 0.9).
    settle_frames: int = integer(20, minimum=0)
    morph_kernel_px: int = integer(5, minimum=1)
    mask_margin_px: int = integer(8, minimum=0)
    # The box the default static rig sees whole
    # (robots.simulation.cell_video.intruders.MONITORED_VOLUME).
    volume_min_m: tuple[float, float, float] = MONITORED_VOLUME.lo_m
    volume_max_m: tuple[float, float, float] = MONITORED_VOLUME.hi_m
    # Nearest depth searched by the stereo match (corners closer to the rig count as this).
    min_depth_m: float = positive(0.3)
    # Depth is matched at 1/stereo_downscale resolution: at 1 m a 2 px disparity step of the
    # static rig (f 640 px, b 0.25 m) is 12 mm, far below what the volume check needs.
    stereo_downscale: int = integer(2, minimum=1, maximum=4)
    stereo_block_px: int = integer(5, minimum=3, maximum=11)
    # Fewer of a component's pixels matched than this: its depth is unknown (not confirmed).
    min_valid_fraction: float = fraction(0.1)
    min_inside_fraction: float = fraction(0.3)
    # A point counts as in the volume within this of the box (the protective separation of
    # ISO 13855): a hand at 1.6 m/s covers 0.107 m in a frame period at 15 fps, so an intruder
    # whose axis reaches the box between two frames (or before a capture the next frame would
    # have stopped) is already flagged on the frame before, and one whose hand alone pokes into
    # the box, the rest of it outside, is flagged by its points near the box.
    approach_margin_m: float = non_negative(0.1)
    # Pixels of a confirmed intrusion are not learnt by the background model (dilated by this,
    # for the motion until the next frame): a person standing still stays an intrusion.
    hold_margin_px: int = integer(16, minimum=0)
    # A confirmed intruder that is no longer a candidate stays an intrusion while at least this
    # share of the pixels it last covered is still foreground or cannot be judged (under the
    # robot's mask, or not yet seen free): a forearm standing behind or in front of the stopped
    # arm is hidden, not gone.
    min_hidden_fraction: float = fraction(0.5)
    max_candidates: int = integer(3, minimum=1)
    clear_time_s: float = non_negative(1.0)

    def __post_init__(self) -> None:
        check_fields("monitor", self)
        _check_box("monitor", self.volume_min_m, self.volume_max_m)

    def inside(self, p_W: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """(N,) bool: which points (N, 3) lie in the monitored volume grown by margin_m."""
        p_W = np.atleast_2d(p_W)
        lo, hi = self.box_m(margin_m)
        return np.all((p_W >= lo) & (p_W <= hi), axis=1)

    def box_m(self, margin_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The monitored volume's corners (3,), (3,) grown by margin_m on every side."""
        return (
            np.asarray(self.volume_min_m, float) - margin_m,
            np.asarray(self.volume_max_m, float) + margin_m,
        )


@dataclass(frozen=True, eq=False)
class Detection:
    """What one frame says about the cell.

    intrusion: a candidate confirmed inside the monitored volume by stereo on this frame
    (depth_confirmed), or the continuation of one confirmed before (overlapping it).
    area_px, centroid_px: of the reported component (the largest confirmed one, else the largest
    candidate) in full-resolution left-image pixels; 0 and None without a candidate.
    point_W: its 3D centroid (m) when stereo found its depth, else None.
    candidates: components above min_area_px outside the robot/object masks.
    cell_clear: no intrusion for clear_time_s and the background model warmed up: the scan may
    (re)start.
    """

    t_s: float
    intrusion: bool
    area_px: int
    centroid_px: tuple[float, float] | None
    point_W: np.ndarray | None
    depth_confirmed: bool
    candidates: int
    cell_clear: bool


@dataclass(frozen=True, eq=False)
class DepthCheck:
    """The stereo verdict on one component: its world centroid (median of its points, or None
    without enough depth), the fraction of its matched pixels, the fraction of its points inside
    the volume (grown by approach_margin_m) and whether it is confirmed inside."""

    point_W: np.ndarray | None
    valid_fraction: float
    inside_fraction: float
    confirmed: bool


# OpenCV's StereoSGBM returns fixed-point disparities with 4 fractional bits.
_SGBM_SCALE = 16.0


def depth_check(
    rig: StereoRig,
    config: MonitorConfig,
    left_rect: np.ndarray,
    right_rect: np.ndarray,
    mask_rect: np.ndarray,
    d_range: tuple[int, int],
) -> DepthCheck:
    """Semi-global matching (OpenCV's StereoSGBM) of the rows of a component's rectified
    bounding box, at 1/`stereo_downscale` resolution, over disparities d_range = (d_lo, d_hi)
    full-resolution px; the component's matched pixels (mask_rect, uint8, rectified left grid)
    are lifted to the world. A forearm is nearly uniform: its inside matches only through the
    smoothness SGM carries in from its silhouette, which a masked block match would not have."""
    none = DepthCheck(None, 0.0, 0.0, False)
    x, y, w, h = cv2.boundingRect(mask_rect)
    if w == 0 or h == 0:
        return none
    s = config.stereo_downscale
    block = config.stereo_block_px
    d_lo, d_hi = d_range
    lo = d_lo // s
    num = 16 * math.ceil((d_hi / s - lo + 1) / 16)
    # Rows with room for the block; columns from the farthest match of the box's left edge.
    y0, y1 = max(0, y - block * s), min(mask_rect.shape[0], y + h + block * s)
    x0, x1 = max(0, x - (lo + num + block) * s), x + w
    size = ((x1 - x0) // s, (y1 - y0) // s)
    # Whole s x s blocks, so that a strip pixel maps back to full resolution exactly.
    x1, y1 = x0 + size[0] * s, y0 + size[1] * s
    # Near the image's left edge fewer disparities fit (SGBM needs them inside the strip).
    num = min(num, 16 * ((size[0] - lo - block // 2 - 1) // 16))
    if num < 16 or size[1] < 2 * block:
        return none
    strips = [
        cv2.resize(im[y0:y1, x0:x1], size, interpolation=cv2.INTER_AREA)
        for im in (left_rect, right_rect)
    ]
    mask = cv2.resize(mask_rect[y0:y1, x0:x1], size, interpolation=cv2.INTER_NEAREST) > 0
    matcher = cv2.StereoSGBM_create(
        minDisparity=lo,
        numDisparities=num,
        blockSize=block,
        # OpenCV's suggested penalties for one channel: 8 and 32 times the block area.
        P1=8 * block * block,
        P2=32 * block * block,
        uniquenessRatio=0,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )
    raw = matcher.compute(strips[0], strips[1])
    found = mask & (raw >= lo * _SGBM_SCALE)
    n_mask = int(np.count_nonzero(mask))
    valid_fraction = float(np.count_nonzero(found)) / max(n_mask, 1)
    if n_mask == 0 or valid_fraction < config.min_valid_fraction:
        return DepthCheck(None, valid_fraction, 0.0, False)
    v, u = np.nonzero(found)
    d = raw[v, u].astype(np.float64) / _SGBM_SCALE
    # Back to full-resolution rectified pixels (centres of the s x s blocks).
    uvd = np.stack([(u + 0.5) * s - 0.5 + x0, (v + 0.5) * s - 0.5 + y0, d * s], axis=1)
    p_W = lift_rectified_W(rig, uvd)
    inside = float(np.mean(config.inside(p_W, config.approach_margin_m)))
    return DepthCheck(
        np.median(p_W, axis=0), valid_fraction, inside, inside >= config.min_inside_fraction
    )


def _odd(n: float) -> int:
    n = max(1, int(round(n)))
    return n if n % 2 else n + 1


def _ellipse(size: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


class IntrusionDetector:
    """Feed every frame in time order; `update` says whether someone is in the cell.

    The first `warmup_frames` frames only train the background model (no intrusion, and the cell
    is not reported clear). The robot mask must be the left image's robot (and tool) pixels at
    the frame's measured joints; `mask_margin_px` is added here.
    """

    def __init__(self, rig: StereoRig, config: MonitorConfig | None = None) -> None:
        self.rig = rig
        self.config = config or MonitorConfig()
        c = self.config
        s = c.downscale
        w, h = rig.image_size
        self._size_small = (w // s, h // s)
        self._bg = cv2.createBackgroundSubtractorMOG2(
            history=c.bg_history_frames, varThreshold=c.bg_var_threshold, detectShadows=False
        )
        self._margin_kernel = _ellipse(2 * math.ceil(c.mask_margin_px / s) + 1)
        self._morph_kernel = _ellipse(_odd(c.morph_kernel_px / s))
        self._hold_kernel = _ellipse(2 * math.ceil(c.hold_margin_px / s) + 1)
        self._hold: np.ndarray | None = None
        self._held_core: np.ndarray | None = None
        d_min, d_max = disparity_range(rig, *c.box_m(c.approach_margin_m), c.min_depth_m)
        # Search a quarter beyond the volume's disparities on both sides, so that a component
        # just outside the volume finds its true depth instead of a false minimum at the edge.
        pad = 0.25 * (d_max - d_min) + 4
        self._d_range = (max(0, math.floor(d_min - pad)), min(w - 1, math.ceil(d_max + pad)))
        self._seen = None
        self._seen_count = None
        self._prev: list[tuple[np.ndarray, np.ndarray]] = []
        self._frames = 0
        self._last_intrusion_t = -math.inf
        self._first_ready_t: float | None = None

    @property
    def ready(self) -> bool:
        return self._frames >= self.config.warmup_frames

    def _small(self, image: np.ndarray) -> np.ndarray:
        if self.config.downscale == 1:
            return image
        return cv2.resize(image, self._size_small, interpolation=cv2.INTER_AREA)

    def _small_mask(self, robot_mask, object_mask) -> np.ndarray:
        """uint8 255 where the robot or object is (any of a block's pixels), plus the margin."""
        m = np.asarray(robot_mask, bool)
        if object_mask is not None:
            m = m | np.asarray(object_mask, bool)
        small = self._small(m.view(np.uint8) * np.uint8(255))
        small = cv2.threshold(small, 0, 255, cv2.THRESH_BINARY)[1]
        return cv2.dilate(small, self._margin_kernel)

    def _check_inputs(self, left, right, robot_mask, object_mask) -> None:
        w, h = self.rig.image_size
        for name, a in (("left", left), ("right", right)):
            if a.shape != (h, w) or a.dtype != np.uint8:
                raise ScannerError(
                    f"monitor: the {name} image must be {w}x{h} grey uint8 (the rig's model), "
                    f"got shape {a.shape} {a.dtype}"
                )
        for name, m in (("robot_mask", robot_mask), ("object_mask", object_mask)):
            if m is not None and np.shape(m) != (h, w):
                raise ScannerError(f"monitor: {name} must be {h}x{w}, got {np.shape(m)}")

    def update(
        self,
        left: np.ndarray,
        right: np.ndarray,
        robot_mask: np.ndarray,
        t_s: float,
        object_mask: np.ndarray | None = None,
    ) -> Detection:
        """One frame: grey uint8 left/right images (original, distorted), the robot mask (bool,
        left image) at the frame's measured joints, the frame time (s) and optionally the hung
        object's mask."""
        self._check_inputs(left, right, robot_mask, object_mask)
        c = self.config
        small = self._small(left)
        mask = self._small_mask(robot_mask, object_mask)
        unmasked = mask == 0
        learn = unmasked if self._hold is None else unmasked & (self._hold == 0)
        if self._seen is None:
            self._seen = small.copy()
            self._seen_count = np.zeros(small.shape, np.uint16)
        self._frames += 1
        # Judged against the model as it was, then learnt: only what the model saw of the cell,
        # under the robot (and a held intruder) the last grey seen there.
        fg_bg = self._bg.apply(small, learningRate=0.0) if self._frames > 1 else None
        np.copyto(self._seen, small, where=learn)
        # A running mean while warming up, then OpenCV's 1/history: a person standing still is
        # not learnt as background within a few frames once the cell is being watched.
        n = self._frames if self._frames <= c.warmup_frames else c.bg_history_frames
        self._bg.apply(self._seen, learningRate=1.0 / n)
        count = self._seen_count
        np.add(count, unmasked, out=count, where=count < 60000)

        motion = None
        if len(self._prev) == 2:
            (p1, m1), (p2, m2) = self._prev
            thr = c.diff_threshold
            d1 = cv2.threshold(cv2.absdiff(small, p1), thr, 255, cv2.THRESH_BINARY)[1]
            d2 = cv2.threshold(cv2.absdiff(p1, p2), thr, 255, cv2.THRESH_BINARY)[1]
            robot_any = cv2.bitwise_or(cv2.bitwise_or(mask, m1), m2)
            motion = cv2.bitwise_and(cv2.bitwise_and(d1, d2), cv2.bitwise_not(robot_any))
        self._prev = [(small, mask)] + self._prev[:1]

        if not self.ready:
            return Detection(t_s, False, 0, None, None, False, 0, False)
        if self._first_ready_t is None:
            self._first_ready_t = t_s
        settled = (count >= c.settle_frames) & unmasked
        fg = np.where(settled, fg_bg, 0).astype(np.uint8)
        if motion is not None:
            fg = cv2.bitwise_or(fg, motion)
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self._morph_kernel)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self._morph_kernel)
        detection, core = self._decide(fg, fg_bg, settled, left, right, t_s)
        if core is None and self._held_core is not None:
            hidden = self._hidden(fg_bg, settled, t_s, detection.candidates)
            if hidden.intrusion:
                detection, core = hidden, self._held_core
        self._held_core = core
        self._hold = None if core is None else cv2.dilate(core, self._hold_kernel)
        if detection.intrusion:
            self._last_intrusion_t = t_s
        since = t_s - max(self._last_intrusion_t, self._first_ready_t)
        clear = not detection.intrusion and since >= c.clear_time_s
        return Detection(
            t_s,
            detection.intrusion,
            detection.area_px,
            detection.centroid_px,
            detection.point_W,
            detection.depth_confirmed,
            detection.candidates,
            clear,
        )

    def _hidden(self, fg_bg, settled, t_s: float, candidates: int) -> Detection:
        """A confirmed intruder no candidate shows any more: still an intrusion while the pixels
        it last covered are mostly foreground or hidden (see min_hidden_fraction)."""
        core = self._held_core > 0
        # Foreground where it was or within hold_margin_px of it, or its pixels now covered by
        # the robot's mask. Not the mask's own margin around the hold: next to an arm stopped
        # for the intrusion it would hold the alarm for ever.
        unknown = ((self._hold > 0) & (fg_bg > 0)) | (core & ~settled)
        share = np.count_nonzero(unknown) / max(np.count_nonzero(core), 1)
        if share < self.config.min_hidden_fraction:
            return Detection(t_s, False, 0, None, None, False, candidates, False)
        s = self.config.downscale
        v, u = np.nonzero(core)
        centroid = (float((u.mean() + 0.5) * s - 0.5), float((v.mean() + 0.5) * s - 0.5))
        return Detection(t_s, True, int(len(u) * s * s), centroid, None, False, candidates, False)

    def _decide(self, fg, fg_bg, settled, left, right, t_s) -> tuple[Detection, np.ndarray | None]:
        """The reported detection and the confirmed components' pixels (downscaled grid)."""
        c = self.config
        s = c.downscale
        n, labels, stats, centroids = cv2.connectedComponentsWithStats(fg, connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA] * s * s
        big = [i + 1 for i in np.argsort(-areas) if areas[i] >= c.min_area_px]
        if not big:
            return Detection(t_s, False, 0, None, None, False, 0, False), None
        rect = self.rig.rect
        left_rect, right_rect = rectify_pair(rect, left, right)
        w, h = self.rig.image_size
        reported, confirmed = None, []
        for i in big[: c.max_candidates]:
            x, y, bw, bh = stats[i, :4]
            component = labels[y : y + bh, x : x + bw] == i
            # The current frame's own evidence (background model) places the depth patch on
            # the intruder where it is now; differencing marks where it was a frame ago.
            now = component & (fg_bg[y : y + bh, x : x + bw] > 0) & settled[y : y + bh, x : x + bw]
            if np.count_nonzero(now) * s * s >= 0.25 * c.min_area_px:
                component = now
            full = np.zeros((h, w), np.uint8)
            block = np.repeat(np.repeat(component.view(np.uint8) * np.uint8(255), s, 0), s, 1)
            full[y * s : y * s + block.shape[0], x * s : x * s + block.shape[1]] = block
            mask_rect = cv2.remap(full, *rect.maps_left, cv2.INTER_NEAREST)
            check = depth_check(self.rig, c, left_rect, right_rect, mask_rect, self._d_range)
            centroid = (
                float((centroids[i, 0] + 0.5) * s - 0.5),
                float((centroids[i, 1] + 0.5) * s - 0.5),
            )
            # A held intruder stays held while it is a candidate, even on a frame whose stereo
            # match fails (a uniform forearm on a uniform table matches only at its edges).
            held = self._hold is not None and np.any(
                self._hold[y : y + bh, x : x + bw][labels[y : y + bh, x : x + bw] == i]
            )
            record = Detection(
                t_s,
                check.confirmed or held,
                int(areas[i - 1]),
                centroid,
                check.point_W,
                check.confirmed,
                len(big),
                False,
            )
            if check.confirmed or held:
                confirmed.append(i)
                if reported is None or not reported.intrusion:
                    reported = record
            reported = reported or record
        hold = None
        if confirmed:
            hold = np.isin(labels, confirmed).view(np.uint8) * np.uint8(255)
        return reported, hold
