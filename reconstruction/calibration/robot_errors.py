"""The robot's own errors: joint zero offsets and link lengths, estimated with X_FC. Pure numeric.

An arm reports joint angles; its flange pose is the kinematics of those angles. An encoder
whose zero is off turns every pose about that joint's axis, and a link a fraction of a
millimetre longer than its drawing moves the flange differently in every pose: systematic
errors that a hand-eye fit without them spreads over X_FC and the per-pose robot corrections.
On a real 70-view set a joint fit predicted held-out views better and moved X_FC by millimetres.

Not every parameter can be told from the rest: joint 1 turns the whole arm about the base axis,
as a turn of the board's pose would; joint 6 turns the flange about its own axis, as a turn of
X_FC would; the shoulder height moves the arm as the board's height would, the last link's
length as X_FC would; and poses that hardly move a joint leave its parameters to X_FC and the
board pose. `observable` decides from the data: a parameter is estimated only when the change
it makes to the images is not (almost) a change other parameters would make too.
The estimate is kept only when it predicts held-out views better (`estimate`): a model with more
parameters always fits its own data better.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize._numdiff import approx_derivative

from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.held_out import Folds, Solution, held_out_refined
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.refine import (
    Linearization,
    Refinement,
    refine_on_board,
    reprojection_residuals,
    sensor_points,
)
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.transforms import twist_to_pose
from reconstruction.stereo.camera_model import PinholeCamera, StereoCamera


@dataclass(frozen=True, eq=False)
class ArmModel:
    """An arm's kinematics with error parameters p: flange_pose(q, p) is the flange pose X_WF
    for the reported joints q. p[:joint_count] are the joints' zero offsets (rad; true =
    reported + offset), the rest corrections of the links `length_keys` (m; their words
    `length_words`); p = 0 is the arm as drawn, so flange_pose(q, 0) is what the controller
    reports. `arm_name`: the arm these parameters belong to (a scan of another arm cannot use
    them)."""

    flange_pose: Callable[[np.ndarray, np.ndarray], np.ndarray]
    length_keys: tuple[str, ...] = ()
    length_words: tuple[str, ...] = ()
    arm_name: str = ""
    joint_count: int = 6

    @property
    def size(self) -> int:
        return self.joint_count + len(self.length_keys)

    def is_joint(self, k: int) -> bool:
        return k < self.joint_count

    def name(self, k: int) -> str:
        if self.is_joint(k):
            return f"joint {k + 1} zero"
        return self.length_words[k - self.joint_count]

    def words(self, k: int, value: float, sigma: float) -> str:
        if self.is_joint(k):
            return f"{self.name(k)} {np.degrees(value):+.4f} +/- {np.degrees(sigma):.4f} deg"
        return f"{self.name(k)} {1e3 * value:+.3f} +/- {1e3 * sigma:.3f} mm"

    def hidden_always(self, k: int) -> str | None:
        """Why parameter k can never be told apart from the board pose and X_FC, if so."""
        if k == 0:
            return "it turns the whole arm about the base axis, as a turn of the board's pose would"
        if k == self.joint_count - 1:
            return "it turns the flange about its own axis, as a turn of X_FC would"
        return None


# How often the per-pose robot error left after the arm's parameters is measured and the fit
# repeated (it settles within three rounds on the simulator, with or without link errors).
REWEIGHT_ROUNDS = 3


def observable(
    board: BoardSpec,
    observations: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    X_FC: np.ndarray,
    X_WB: np.ndarray,
    arm: ArmModel,
    min_independence: float,
) -> tuple[tuple[int, ...], dict[int, str]]:
    """The arm parameters these poses determine, and why each other is not.

    A parameter's independence is the sine of the angle between the image change it makes (the
    Jacobian column over every board point) and the span of the changes X_FC, the board pose
    and the other kept parameters make: 0 when some combination of those imitates it exactly.
    The least independent is dropped while it is below `min_independence`."""
    sensors = sensor_points(board, observations, cameras)
    joints = np.array([o.q_rad for o in observations], float)
    P = arm.size

    def fun(x: np.ndarray) -> np.ndarray:
        X_WF = np.array([arm.flange_pose(q, x[12:]) for q in joints])
        r = reprojection_residuals(
            sensors, X_WF, X_FC @ twist_to_pose(x[:6]), X_WB @ twist_to_pose(x[6:12])
        )
        return np.concatenate([v.ravel() for v in r])

    J = approx_derivative(fun, np.zeros(12 + P), method="3-point", abs_step=1e-6)
    norms = np.linalg.norm(J, axis=0)
    Jn = J / np.where(norms > 0, norms, 1.0)
    kept = [k for k in range(P) if norms[12 + k] > 0]
    reasons = {k: "it changes nothing in these images" for k in range(P) if k not in kept}
    while kept:
        independence = {}
        for k in kept:
            others = Jn[:, list(range(12)) + [12 + i for i in kept if i != k]]
            column = Jn[:, 12 + k]
            coef = np.linalg.lstsq(others, column, rcond=None)[0]
            independence[k] = float(np.linalg.norm(column - others @ coef))
        k = min(independence, key=independence.get)
        if independence[k] >= min_independence:
            break
        kept.remove(k)
        reasons[k] = arm.hidden_always(k) or (
            f"these poses cannot tell it from X_FC, the board pose and the other parameters "
            f"(independence {independence[k]:.3f}, need >= {min_independence:g})"
        )
    return tuple(kept), dict(sorted(reasons.items()))


def parameter_sigma(lin: Linearization, indices: Sequence[int]) -> np.ndarray:
    """Standard deviations of the linearised problem's parameters `indices` (the marginal of
    s^2 (J^T W J)^-1, s^2 the weighted residual variance per degree of freedom)."""
    w = lin.irls
    J = lin.J.multiply(np.sqrt(w)[:, None]).toarray()
    m, n = J.shape
    s2 = float(np.sum(w * lin.f**2)) / max(m - n, 1)
    try:
        cols = np.linalg.solve(J.T @ J, np.eye(n)[:, list(indices)])
    except np.linalg.LinAlgError:
        return np.full(len(indices), np.nan)
    return np.sqrt(np.clip(s2 * np.diag(cols[list(indices)]), 0.0, None))


@dataclass(frozen=True, eq=False)
class RobotErrors:
    """The outcome of `--robot-offsets`: the arm parameters estimated (indices into ArmModel's
    p), their values (0 where not estimated or not kept) and sigmas (NaN where not estimated),
    why the others were not, held-out prediction RMS (px) without and with them, whether they
    were kept, and the sentence that says so."""

    estimated: tuple[int, ...]
    params: np.ndarray
    sigma: np.ndarray
    not_observable: dict[int, str]
    held_out_px_without: float
    held_out_px_with: float
    kept: bool
    note: str
    names: tuple[str, ...] = ()
    length_keys: tuple[str, ...] = ()
    joint_count: int = 6
    arm_name: str = ""

    @property
    def joint_offsets_rad(self) -> np.ndarray:
        return self.params[: self.joint_count]

    @property
    def link_length_corrections_m(self) -> dict[str, float]:
        """The estimated length corrections by the arm model's keys (only those estimated)."""
        return {
            key: float(self.params[self.joint_count + i])
            for i, key in enumerate(self.length_keys)
            if self.joint_count + i in self.estimated
        }

    def as_dict(self) -> dict:
        def name(k: int) -> str:
            return self.names[k] if k < len(self.names) else str(k)

        return {
            "estimated": [name(k) for k in self.estimated],
            "kept": self.kept,
            "joint_offsets_rad": self.joint_offsets_rad.tolist(),
            "link_length_corrections_m": self.link_length_corrections_m,
            "sigma": {
                name(k): float(self.sigma[k]) for k in self.estimated if np.isfinite(self.sigma[k])
            },
            "not_observable": {name(k): why for k, why in self.not_observable.items()},
            "held_out_px_without": self.held_out_px_without,
            "held_out_px_with": self.held_out_px_with,
            "note": self.note,
        }


def not_estimated(
    note: str, size: int = 6, not_observable: dict[int, str] | None = None
) -> RobotErrors:
    """No estimate (the data lack what it needs): the calibration goes on without one."""
    nan = float("nan")
    return RobotErrors(
        (), np.zeros(size), np.full(size, nan), not_observable or {}, nan, nan, False, note
    )


def _arm_fields(arm: ArmModel) -> dict:
    """The fields of RobotErrors that name the arm's parameters."""
    return {
        "names": tuple(arm.name(k) for k in range(arm.size)),
        "length_keys": arm.length_keys,
        "joint_count": arm.joint_count,
        "arm_name": arm.arm_name,
    }


def _note(arm: ArmModel, outcome: RobotErrors, values: np.ndarray) -> str:
    named = ", ".join(arm.words(k, values[k], outcome.sigma[k]) for k in outcome.estimated)
    if outcome.kept:
        verdict = (
            f"kept: held-out prediction {outcome.held_out_px_with:.3f} px with them against "
            f"{outcome.held_out_px_without:.3f} px without"
        )
    else:
        verdict = (
            f"not kept: held-out prediction {outcome.held_out_px_with:.3f} px with them is no "
            f"better than {outcome.held_out_px_without:.3f} px without"
        )
    hidden = "; ".join(f"{arm.name(k)}: {why}" for k, why in outcome.not_observable.items())
    return f"robot errors {named}; {verdict}" + (f" (not estimated: {hidden})" if hidden else "")


def estimate(
    board: BoardSpec,
    inliers: Sequence[PoseObservation],
    cameras: StereoCamera | PinholeCamera,
    refined: Refinement,
    settings: CalibrationSettings,
    arm: ArmModel | None,
    folds: Folds,
) -> tuple[Refinement, RobotErrors]:
    """The refinement with the observable arm parameters when they predict held-out views
    better, else `refined` as it is; and the outcome either way. Data without joint angles or
    without an observable parameter calibrate without them (said in the outcome's note)."""
    if arm is None or any(o.q_rad is None for o in inliers):
        return refined, not_estimated(
            "robot errors not estimated: the poses carry no joint angles (only flange poses), "
            "and the joint offsets need them; calibrated without them",
            6 if arm is None else arm.size,
        )
    found, hidden = observable(
        board,
        inliers,
        cameras,
        refined.X_FC,
        refined.X_WB,
        arm,
        settings.offset_min_independence,
    )
    if not any(arm.is_joint(k) for k in found):
        why = "; ".join(f"{arm.name(k)}: {w}" for k, w in hidden.items() if arm.is_joint(k))
        outcome = not_estimated(
            f"robot errors not estimated: no joint's zero offset is observable from these "
            f"{len(inliers)} poses ({why}); record poses that move joints 2-{arm.joint_count - 1} "
            "more, or "
            "calibrate without --robot-offsets",
            arm.size,
            hidden,
        )
        return refined, RobotErrors(**{**outcome.__dict__, **_arm_fields(arm)})
    joints = np.array([o.q_rad for o in inliers], float)
    zero = np.zeros(arm.size)

    def fit(start: Refinement, weights: CalibrationSettings, params0: np.ndarray) -> Refinement:
        return refine_on_board(
            board,
            inliers,
            cameras,
            start.X_FC,
            start.X_WB,
            weights,
            joints=joints,
            flange_pose=arm.flange_pose,
            estimated=found,
            params0=params0,
        )

    with_arm = fit(refined, settings, zero)
    # Once the arm's systematic errors are modelled, what is left of each pose's error is much
    # smaller than the arm's stated accuracy; weighed with that accuracy the per-pose
    # corrections stay free to absorb what the parameters should explain (joints 2 and 3 then
    # split their offsets up to 0.005 deg wrongly on the simulator, 0.001 deg after this). The
    # remaining error is measured from the corrections, as the image noise is from the
    # residuals, down to the arm's repeatability, and the fit repeated with it.
    for _ in range(REWEIGHT_ROUNDS):
        if with_arm.corrections.size == 0:
            break
        measured = replace(
            settings,
            robot_translation_sigma_m=max(
                settings.min_robot_translation_sigma_m,
                float(np.sqrt(np.mean(with_arm.corrections[:, 3:] ** 2))),
            ),
            robot_rotation_sigma_rad=max(
                settings.min_robot_rotation_sigma_rad,
                float(np.sqrt(np.mean(with_arm.corrections[:, :3] ** 2))),
            ),
        )
        with_arm = fit(with_arm, measured, with_arm.robot_params)
    without = held_out_refined(
        board,
        inliers,
        cameras,
        refined.linearization,
        Solution(refined.X_FC, refined.X_WB),
        (),
        folds,
    )
    with_ = held_out_refined(
        board,
        inliers,
        cameras,
        with_arm.linearization,
        Solution(with_arm.X_FC, with_arm.X_WB, with_arm.robot_params),
        found,
        folds,
        arm.flange_pose,
    )
    sigma = np.full(arm.size, np.nan)
    sigma[list(found)] = parameter_sigma(with_arm.linearization, range(12, 12 + len(found)))
    kept = with_.rms_px < without.rms_px
    values = with_arm.robot_params
    outcome = RobotErrors(
        found,
        values if kept else zero,
        sigma,
        hidden,
        without.rms_px,
        with_.rms_px,
        kept,
        "",
        **_arm_fields(arm),
    )
    outcome = RobotErrors(**{**outcome.__dict__, "note": _note(arm, outcome, values)})
    return (with_arm if kept else refined), outcome
