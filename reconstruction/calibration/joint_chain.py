"""A serial arm's kinematics as numbers, and its error parameters for a calibration. Pure numeric.

An arm hands the calibration a `JointChain`: for each movable joint, base to flange, the fixed
transform from the previous joint's moving frame (the world for the first) to this joint's
frame, and the joint's axis in that frame; then the fixed transform to the flange. That is what
a URDF or SDF states, so any serial arm a model file describes has one, whatever its geometry.

Its error parameters (`chain_arm_model`): every joint's zero offset (rad, or m for a prismatic
joint; true = reported + offset), then a correction of the length of every fixed translation
after the first joint (m, along the translation as drawn: a link longer or shorter than its
drawing). The first joint's own placement is left out: moving it moves the whole arm, as moving
the board would, so no image can tell it from the board pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction.calibration.robot_errors import ArmModel
from reconstruction.common.transforms import make_pose, rotation_about

# A fixed translation shorter than this is no link (a joint placed where the previous one is):
# it has no length to correct.
MIN_LINK_LENGTH_M = 1e-6


@dataclass(frozen=True, eq=False)
class JointChain:
    """An arm's kinematic chain, read-only arrays, n movable joints base to flange.

    X_MF: (n + 1, 4, 4): [0] the first joint's frame in the world (the arm's base placement),
    [i] joint i's frame in joint i-1's moving frame, [n] the flange frame in joint n-1's moving
    frame. axes: (n, 3) unit axes in each joint's frame. revolute: (n,) True for a revolute
    joint (rotation about the axis), False for a prismatic one (translation along it)."""

    arm_name: str
    joint_names: tuple[str, ...]
    flange_name: str
    X_MF: np.ndarray
    axes: np.ndarray
    revolute: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        shapes = {"X_MF": (n + 1, 4, 4), "axes": (n, 3), "revolute": (n,)}
        for name, shape in shapes.items():
            value = np.array(getattr(self, name), bool if name == "revolute" else float)
            if value.shape != shape:
                raise ValueError(f"chain of {self.arm_name}: {name} must be {shape}")
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def joint_count(self) -> int:
        return len(self.joint_names)


def joint_motion(axis: np.ndarray, revolute: bool, q: float) -> np.ndarray:
    """X_FM of one joint at position q: a turn about `axis` or a shift along it."""
    if revolute:
        return make_pose(rotation_about(axis, q), np.zeros(3))
    return make_pose(np.eye(3), q * np.asarray(axis, float))


def link_indices(chain: JointChain) -> tuple[int, ...]:
    """The fixed transforms of X_MF whose length a calibration may correct (see the module)."""
    lengths = np.linalg.norm(chain.X_MF[:, :3, 3], axis=1)
    return tuple(i for i in range(1, chain.joint_count + 1) if lengths[i] > MIN_LINK_LENGTH_M)


def link_name(chain: JointChain, i: int) -> str:
    """The link that ends at X_MF[i]: named after the joint (or flange) it carries."""
    return chain.flange_name if i == chain.joint_count else chain.joint_names[i]


def chain_flange_pose(
    chain: JointChain,
    q: np.ndarray,
    offsets: np.ndarray | None = None,
    length_corrections_m: dict[int, float] | None = None,
) -> np.ndarray:
    """X_WF (4x4) at reported joints q (n,): with joint zero `offsets` (n,) and link length
    corrections {index into X_MF: metres}, the arm a calibration found; without, as drawn."""
    q = np.asarray(q, float) if offsets is None else np.asarray(q, float) + offsets
    X = chain.X_MF[0].copy()
    for i in range(chain.joint_count):
        X = X @ joint_motion(chain.axes[i], bool(chain.revolute[i]), q[i])
        X = X @ _stretched(chain.X_MF[i + 1], (length_corrections_m or {}).get(i + 1, 0.0))
    return X


def _stretched(X: np.ndarray, correction_m: float) -> np.ndarray:
    if correction_m == 0.0:
        return X
    out = X.copy()
    p = X[:3, 3]
    out[:3, 3] = p + correction_m * p / np.linalg.norm(p)
    return out


def chain_arm_model(chain: JointChain) -> ArmModel:
    """The chain's kinematics with error parameters p: the n joint zero offsets, then one
    length correction per `link_indices` (keys `<link>_length_m`)."""
    n = chain.joint_count
    links = link_indices(chain)

    def flange_pose(q: np.ndarray, p: np.ndarray) -> np.ndarray:
        corrections = {i: float(v) for i, v in zip(links, p[n:], strict=True) if v != 0.0}
        return chain_flange_pose(chain, q, p[:n], corrections)

    return ArmModel(
        flange_pose,
        tuple(f"{link_name(chain, i)}_length_m" for i in links),
        tuple(f"length before {link_name(chain, i)}" for i in links),
        arm_name=chain.arm_name,
        joint_count=n,
    )
