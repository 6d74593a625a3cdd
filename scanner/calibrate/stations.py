"""Where the camera goes to calibrate: K board views chosen for good hand-eye conditioning.

Candidates: the rig centre on a cone around the board normal (tilt up to max_tilt_rad), at
distances in [distance_min_m, distance_max_m], aimed at points near the board centre, with a
camera roll in [-max_roll_rad, max_roll_rad]. A candidate counts when the arm reaches it without
collision (the `reachable` function: IK + collision check now, the planner's once merged) and the
whole board stays inside both images by image_margin_px under the NOMINAL model (the margin
absorbs the few-mm, 1-degree hand-eye error). From those, K are picked by farthest-point sampling
in orientation (plus a little position): large rotations between stations, about varied axes,
which is what AX = XB needs (Tsai & Lenz 1989: error falls with the angle between motions' axes).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planners.ik import Viewpoint, camera_pose, rig_centre_offset
from reconstruction.calibration.boards import BoardSpec
from reconstruction.common.checks import check_fields, integer, non_negative, require_count
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, rotation_angles_rad, transform_points
from reconstruction.stereo.camera_model import StereoCamera, project_points
from scanner.scan.sampling import farthest_point_sample

ReachableFn = Callable[[Viewpoint], list[np.ndarray]]


@dataclass(frozen=True)
class StationConfig:
    """Calibration stations (units in the names)."""

    count: int = integer(20, minimum=3, maximum=1000)
    distance_min_m: float = 0.35
    distance_max_m: float = 0.50
    max_tilt_rad: float = math.radians(45.0)
    max_roll_rad: float = non_negative(math.radians(90.0))
    target_jitter_m: float = non_negative(0.02)
    candidates: int = 800
    image_margin_px: float = non_negative(40.0)
    # Farthest-point metric: rotation angle (rad) + this weight x distance (m).
    position_weight_rad_per_m: float = non_negative(2.0)
    seed: int = integer(0, minimum=0)

    def __post_init__(self) -> None:
        if self.count < 3:
            raise ScannerError(
                f"stations.count: hand-eye needs at least 3 stations, got {self.count}"
            )
        if not self.distance_min_m > 0:
            raise ScannerError(
                f"stations.distance_min_m: expected a positive distance, got {self.distance_min_m}"
            )
        if not self.distance_min_m <= self.distance_max_m:
            raise ScannerError(
                f"stations.distance_max_m: expected at least stations.distance_min_m "
                f"({self.distance_min_m}), got {self.distance_max_m}"
            )
        if not 0 <= self.max_tilt_rad < math.pi / 2:
            raise ScannerError("stations.max_tilt_rad: must be in [0, pi/2)")
        check_fields("stations", self)
        require_count("stations", self, ("candidates",), minimum=self.count)


@dataclass(frozen=True, eq=False)
class Station:
    """One station: the look-at viewpoint, the joint configuration, and the NOMINAL X_WC."""

    index: int
    viewpoint: Viewpoint
    q: np.ndarray
    X_WC: np.ndarray


@dataclass(frozen=True, eq=False)
class StationPlan:
    stations: tuple[Station, ...]
    candidates: int
    visible: int
    reachable: int


def _board_outline_B(board: BoardSpec) -> np.ndarray:
    """Points along the pattern's border plus half a spacing (the detector needs the quiet zone
    edge of the squares too)."""
    w, h = board.size_m
    m = board.spacing_m / 2
    if board.kind == "circles_asymmetric":
        x0, y0 = -m, -m
    else:
        x0, y0 = 0.0, 0.0
    xs = np.linspace(x0 - m, x0 + w + m, 9)
    ys = np.linspace(y0 - m, y0 + h + m, 7)
    border = [(x, y0 - m) for x in xs] + [(x, y0 + h + m) for x in xs]
    border += [(x0 - m, y) for y in ys] + [(x0 + w + m, y) for y in ys]
    return np.array([(x, y, 0.0) for x, y in border])


def board_in_view(
    board: BoardSpec, X_WB: np.ndarray, X_WC: np.ndarray, stereo: StereoCamera, margin_px: float
) -> bool:
    """The whole board inside both images (nominal model), at least margin_px from the edges."""
    p_B = _board_outline_B(board)
    # Both cameras of the rig: the stereo pair, or an RGB-D device's colour camera (the board's
    # corners) and depth camera (the board's plane for the depth-scale check).
    first, second = (
        (stereo.color, stereo.depth) if hasattr(stereo, "depth") else (stereo.left, stereo.right)
    )
    for camera, X_WS in ((first, X_WC), (second, X_WC @ stereo.X_CR)):
        p_S = transform_points(invert(X_WS) @ X_WB, p_B)
        if np.any(p_S[:, 2] <= 0.05):
            return False
        # Far outside the field the distortion polynomial folds back; reject before projecting.
        if np.any(np.hypot(p_S[:, 0], p_S[:, 1]) / p_S[:, 2] > 1.0):
            return False
        uv = project_points(camera, p_S)
        if (
            np.any(uv < margin_px)
            or np.any(uv[:, 0] > camera.width - margin_px)
            or np.any(uv[:, 1] > camera.height - margin_px)
        ):
            return False
    return True


def _candidates(
    config: StationConfig, board: BoardSpec, X_WB: np.ndarray, rng: np.random.Generator
) -> list[Viewpoint]:
    w, h = board.size_m
    centre = transform_points(X_WB, np.array([[w / 2, h / 2, 0.0]]))[0]
    normal = -X_WB[:3, 2]  # the side the camera sees
    u = X_WB[:3, 0]
    v = X_WB[:3, 1]
    out = []
    for _ in range(config.candidates):
        # Uniform over the spherical cap, not over the tilt angle (which crowds the normal).
        cos_tilt = rng.uniform(math.cos(config.max_tilt_rad), 1.0)
        sin_tilt = math.sqrt(1 - cos_tilt**2)
        phi = rng.uniform(0, 2 * math.pi)
        direction = cos_tilt * normal + sin_tilt * (math.cos(phi) * u + math.sin(phi) * v)
        distance = rng.uniform(config.distance_min_m, config.distance_max_m)
        target = centre + config.target_jitter_m * rng.uniform(-1, 1) * u
        target = target + config.target_jitter_m * rng.uniform(-1, 1) * v
        roll = rng.uniform(-config.max_roll_rad, config.max_roll_rad)
        p_WM = target + distance * direction
        out.append(Viewpoint(tuple(p_WM.tolist()), tuple(target.tolist()), float(roll)))
    return out


def plan_stations(
    config: StationConfig,
    board: BoardSpec,
    X_WB: np.ndarray,
    stereo: StereoCamera,
    X_FC: np.ndarray,
    reachable: ReachableFn,
    q_reference: np.ndarray,
) -> StationPlan:
    """K reachable, collision-free stations that see the whole board, spread in orientation."""
    rng = np.random.default_rng(config.seed)
    X_MC = rig_centre_offset(stereo.X_CR)
    visible, options = 0, []
    for vp in _candidates(config, board, X_WB, rng):
        X_WC = camera_pose(vp, X_MC)
        if not board_in_view(board, X_WB, X_WC, stereo, config.image_margin_px):
            continue
        visible += 1
        qs = reachable(vp)
        if qs:
            q = min(qs, key=lambda q: float(np.abs(q - q_reference).max()))
            options.append((vp, q, X_WC))
    if len(options) < config.count:
        raise ScannerError(
            f"only {len(options)} of {config.candidates} candidate stations see the whole board "
            f"and are reachable without collision ({visible} see it); {config.count} are needed: "
            "move the board closer to the robot, tilt it towards the robot, or widen "
            "stations.distance_*_m / stations.max_tilt_rad"
        )
    R = np.array([X[:3, :3] for _, _, X in options])
    p = np.array([X[:3, 3] for _, _, X in options])
    normal = -X_WB[:3, 2]
    # Start from the most frontal view (the easiest detection), then farthest-point sampling.
    tilts = [float(np.arccos(np.clip(-X[:3, 2] @ normal, -1, 1))) for _, _, X in options]
    weight = config.position_weight_rad_per_m

    def distances_from(i: int) -> np.ndarray:
        return rotation_angles_rad(R, R[i]) + weight * np.linalg.norm(p - p[i], axis=1)

    chosen = farthest_point_sample(config.count, int(np.argmin(tilts)), distances_from)
    stations = tuple(
        Station(k, options[i][0], options[i][1], options[i][2]) for k, i in enumerate(chosen)
    )
    return StationPlan(stations, config.candidates, visible, len(options))
