"""Is the reported uncertainty of X_FC honest? Errors against the simulator's truth in sigmas.

The check: over several seeded calibrations, every axis of the true X_FC error (rotation about
C's x y z, translation along them: X_FC_true = X_FC @ twist_to_pose(delta)) lies within 3 of its
reported standard deviations in all but at most one run in ten. Per axis rather than on the norm:
a sigma that is too small along one axis (the rotation about the optical axis, say) would hide in
a norm dominated by the others.

`board_observations` is the simulator's calibration without rendering (for tests that need ten
calibrations in seconds): the planned default stations, the seeded error model (hand-eye mount
error, encoder zero offsets), the true cameras, and Gaussian corner noise of the size measured on
the renders; `render_free_observations` plans those stations and runs it once per seed.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from reconstruction.calibration.boards import BoardSpec, Detection
from reconstruction.calibration.observations import PoseObservation
from reconstruction.common.transforms import invert, pose_to_twist, transform_points
from reconstruction.stereo.camera_model import StereoCamera, project_points
from robots.simulation.truth import ErrorModel, sample_truth

if TYPE_CHECKING:
    from scanner.calibrate.config import CalibrateConfig

SIGMA_BOUND = 3.0
# findChessboardCornersSB on the simulator's 1280x960 renders: ~0.03 px per coordinate.
RENDERED_CORNER_NOISE_PX = 0.03


def error_in_sigmas(X_FC: np.ndarray, sigma: np.ndarray, X_FC_true: np.ndarray) -> np.ndarray:
    """(6,) |delta| / sigma per axis (rotation x y z, translation x y z, in C)."""
    delta = pose_to_twist(invert(np.asarray(X_FC, float)) @ np.asarray(X_FC_true, float))
    return np.abs(delta) / np.asarray(sigma, float)


@dataclass(frozen=True)
class SigmaSummary:
    """runs: calibrations checked; within_3sigma: runs whose six axes all lie within 3 sigma;
    worst_ratio: the largest |error| / sigma of any axis of any run."""

    runs: int
    within_3sigma: int
    worst_ratio: float

    @property
    def honest(self) -> bool:
        """At least 9 runs in 10 within 3 sigma on every axis."""
        return self.within_3sigma >= 0.9 * self.runs

    def as_dict(self) -> dict:
        return {
            "runs": self.runs,
            "within_3sigma": self.within_3sigma,
            "worst_ratio": round(self.worst_ratio, 3),
        }


def summarise(ratios: Sequence[np.ndarray]) -> SigmaSummary:
    ratios = np.atleast_2d(np.asarray(ratios, float))
    inside = int(np.sum(np.all(ratios <= SIGMA_BOUND, axis=1)))
    return SigmaSummary(len(ratios), inside, float(np.nanmax(ratios)))


def board_observations(
    board: BoardSpec,
    X_WB: np.ndarray,
    stations_q: Sequence[np.ndarray],
    stereo: StereoCamera,
    X_FC_nominal: np.ndarray,
    seed: int,
    flange_pose,
    corner_noise_px: float = RENDERED_CORNER_NOISE_PX,
    true_flange_pose=None,
) -> tuple[list[PoseObservation], np.ndarray, np.ndarray]:
    """Board corners as the true arm (encoder offsets of `ErrorModel(seed)`; its kinematics
    `true_flange_pose`, default the nominal `flange_pose`) and true X_FC see them, X_WF and
    the joints as the controller reports them (`flange_pose(q)`, q); the true X_FC and the
    true joint offsets (true = reported + offset)."""
    truth = sample_truth(ErrorModel(seed=seed), X_FC_nominal, stereo, np.eye(4))
    true_pose = true_flange_pose or flange_pose
    p_B = board.object_points()
    rng = np.random.default_rng([seed, 11])
    out = []
    for k, q in enumerate(stations_q):
        X_WC = true_pose(np.asarray(q) + truth.joint_offsets_rad) @ truth.X_FC
        p_C = transform_points(invert(X_WC) @ X_WB, p_B)
        views = []
        for camera, X_SC in ((stereo.left, np.eye(4)), (stereo.right, invert(stereo.X_CR))):
            pixels = project_points(camera, transform_points(X_SC, p_C))
            pixels = pixels + rng.normal(0.0, corner_noise_px, pixels.shape)
            views.append(Detection(np.arange(len(p_B)), pixels))
        q = np.asarray(q, float)
        out.append(PoseObservation(f"{k:04d}", flange_pose(q), *views, q_rad=q))
    return out, np.array(truth.X_FC), np.array(truth.joint_offsets_rad)


def kinematic_error_robot(robot, seed: int, magnitude_m: tuple[float, float]):
    """The arm with its link lengths off by a random vector whose norm is drawn uniformly in
    `magnitude_m` (per seed): a kinematic error that, unlike an encoder offset, changes the
    flange pose differently in every pose and that no joint offset or X_FC explains.

    The wrist-to-flange length is left exact: an error of it moves the flange along its own
    axis by the same amount in every pose, which is by definition part of the mount (the
    X_FC that the robot's reported poses need, and what a scan uses)."""
    from dataclasses import replace

    rng = np.random.default_rng([seed, 29])
    direction = rng.standard_normal(4)
    e = direction / np.linalg.norm(direction) * rng.uniform(*magnitude_m)
    return replace(
        robot,
        shoulder_height_m=robot.shoulder_height_m + e[0],
        upper_arm_m=robot.upper_arm_m + e[1],
        elbow_offset_m=robot.elbow_offset_m + e[2],
        forearm_m=robot.forearm_m + e[3],
    )


def render_free_observations(
    config: CalibrateConfig,
    seeds: Iterable[int],
    kinematic_error_m: tuple[float, float] | None = None,
) -> list[tuple[list[PoseObservation], np.ndarray, np.ndarray]]:
    """(observations, true X_FC, true joint offsets) per seed of `board_observations` at the
    stations `config` plans: its board where its placement puts it, its camera on the nominal
    mount, stations reached by the IK of `config.robot` from the arm's home joints. With
    `kinematic_error_m` the true RX60's link lengths are off (`kinematic_error_robot`)."""
    # Imported here: the calibration report imports this module for error_in_sigmas alone.
    from planners.ik import camera_pose, ik_camera, rig_centre_offset
    from robots.arms.default import DEFAULT_ROBOT, arm_of
    from robots.arms.rx60 import RX60, fk_flange
    from robots.models.camera_tool import nominal_X_FC
    from scanner.calibrate.stations import plan_stations

    seeds = list(seeds)
    stereo = config.camera.stereo_camera()
    X_FC = nominal_X_FC(stereo.baseline_m)
    X_WB = config.placement.X_WB(config.board)
    arm = arm_of(config.robot)
    X_MC = rig_centre_offset(stereo.X_CR)
    plan = plan_stations(
        config.stations,
        config.board,
        X_WB,
        stereo,
        X_FC,
        lambda v: ik_camera(arm, camera_pose(v, X_MC), X_FC),
        arm.home_q,
    )
    stations_q = [s.q for s in plan.stations]
    if config.robot == DEFAULT_ROBOT:
        # The RX60's closed form, whose link lengths a seed may change.
        robot = RX60()
        nominal, true_arms = (lambda q: fk_flange(robot, q)), {}
        if kinematic_error_m is not None:
            true_arms = {s: kinematic_error_robot(robot, s, kinematic_error_m) for s in seeds}
        true_poses = {s: (lambda q, r=r: fk_flange(r, q)) for s, r in true_arms.items()}
    elif kinematic_error_m is None:
        nominal, true_poses = (lambda q: arm.X_WF(q).GetAsMatrix4()), {}
    else:
        raise ValueError("link length errors are simulated for the RX60 only")
    return [
        board_observations(
            config.board,
            X_WB,
            stations_q,
            stereo,
            X_FC,
            seed,
            nominal,
            true_flange_pose=true_poses.get(seed, nominal),
        )
        for seed in seeds
    ]
