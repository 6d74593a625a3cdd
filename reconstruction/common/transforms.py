"""Rigid transforms as 4x4 numpy arrays (monogram notation: X_AB is the pose of B in A).

The one place for poses and rotations: make, invert, apply, perturb, compare and average them.
Perturbations use the decoupled parametrisation xi = (w, v): R = exp([w]x), t = v. At xi = 0 its
Jacobian equals the SE(3) exponential's, which is all Gauss-Newton needs, and it keeps rotation
and translation tolerances separate, as the reports state them.

Rotation vectors go through Rodrigues' formula in numpy scalars: scipy's Rotation costs ~20x more
per call, and the pose graph and hand-eye loops call this thousands of times. scipy's Rotation
takes over where it is the better tool: near a half turn, for Euler angles and quaternions in
pose files, and for the mean of many rotations.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from reconstruction.common.errors import ScannerError


def make_pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The 4x4 transform with rotation R (3x3) and translation p (3,)."""
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = np.asarray(p, float).ravel()
    return X


def invert(X_AB: np.ndarray) -> np.ndarray:
    """X_BA from X_AB (exact for rigid transforms, unlike np.linalg.inv)."""
    R = X_AB[:3, :3]
    return make_pose(R.T, -R.T @ X_AB[:3, 3])


def transform_points(X_AB: np.ndarray, p_B: np.ndarray) -> np.ndarray:
    """p_A (N, 3) of points p_B (N, 3)."""
    return p_B @ X_AB[:3, :3].T + X_AB[:3, 3]


def rotate_vectors(X_AB: np.ndarray, v_B: np.ndarray) -> np.ndarray:
    """Directions v_B (N, 3) expressed in A (rotation only)."""
    return v_B @ X_AB[:3, :3].T


def skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) vectors -> (N, 3, 3) cross-product matrices."""
    v = np.atleast_2d(v)
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis times angle, rad), by Rodrigues' formula."""
    w = np.asarray(w, float).ravel()
    theta = math.sqrt(float(w @ w))
    K = skew(w)[0]
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + math.sin(theta) / theta * K + (1 - math.cos(theta)) / theta**2 * K @ K


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation by angle_rad about `axis` (any length but zero)."""
    axis = np.asarray(axis, float)
    return rotvec_to_matrix(axis / np.linalg.norm(axis) * angle_rad)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation R (3x3) with R @ a parallel to b (a, b: any length but zero);
    opposite vectors: half a turn about an axis perpendicular to both."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(a @ b)
    if s > 1e-9:
        return rotation_about(axis, math.atan2(s, c))
    if c > 0:
        return np.eye(3)
    other = np.eye(3)[int(np.argmin(np.abs(a)))]
    return rotation_about(np.cross(a, other), math.pi)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Inverse of `rotvec_to_matrix`; near pi it falls back to scipy's robust conversion."""
    c = (np.trace(R) - 1) / 2
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2
    s = float(np.linalg.norm(v))
    if c < -0.99:
        return Rotation.from_matrix(R).as_rotvec()
    # atan2 of sin and cos keeps full precision at small angles, unlike arccos of the trace.
    theta = math.atan2(s, min(max(c, -1.0), 1.0))
    return v * (theta / s) if s > 1e-12 else v


def rotation_angle_rad(R: np.ndarray) -> float:
    """Angle of a rotation matrix, precise near 0 (see `matrix_to_rotvec`)."""
    return float(np.linalg.norm(matrix_to_rotvec(R)))


def rotation_angles_rad(R_AB: np.ndarray, R_AC: np.ndarray) -> np.ndarray:
    """Angles (N,) of the rotations between each of R_AB (N, 3, 3) and R_AC (3, 3), precise near
    0 like `rotation_angle_rad` (vectorised for many orientations at once)."""
    R = np.einsum("kji,jl->kil", R_AB, R_AC)  # R_BC for every B
    c = (np.trace(R, axis1=1, axis2=2) - 1) / 2
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    return np.arctan2(np.linalg.norm(v, axis=1) / 2, np.clip(c, -1.0, 1.0))


def twist_to_pose(xi: np.ndarray) -> np.ndarray:
    """(w, v) -> 4x4 with R = exp([w]x), t = v (decoupled; see the module docstring)."""
    xi = np.asarray(xi, float)
    return make_pose(rotvec_to_matrix(xi[:3]), xi[3:])


def pose_to_twist(X: np.ndarray) -> np.ndarray:
    """Inverse of `twist_to_pose`: (rotation vector, translation)."""
    return np.concatenate([matrix_to_rotvec(X[:3, :3]), X[:3, 3]])


def pose_from_rvec_tvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """OpenCV's (rvec, tvec) of an object O seen by camera C (e.g. solvePnP's) -> X_CO."""
    return make_pose(rotvec_to_matrix(rvec), tvec)


def pose_difference(X_a: np.ndarray, X_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) between two poses of the same frame in the same frame."""
    return (
        float(np.linalg.norm(X_a[:3, 3] - X_b[:3, 3])),
        rotation_angle_rad(X_a[:3, :3].T @ X_b[:3, :3]),
    )


def mean_pose(poses: list[np.ndarray]) -> np.ndarray:
    """Chordal mean: average rotation projected back onto SO(3), arithmetic mean translation."""
    Rs = np.array([X[:3, :3] for X in poses])
    R = Rotation.from_matrix(Rs).mean().as_matrix()
    return make_pose(R, np.mean([X[:3, 3] for X in poses], axis=0))


def check_pose(X: np.ndarray, name: str) -> np.ndarray:
    """A finite 4x4 rigid transform as a float array; poses come from files, hence ScannerError."""
    X = np.asarray(X, dtype=float)
    if X.shape != (4, 4) or not np.all(np.isfinite(X)):
        raise ScannerError(f"{name}: expected a finite 4x4 transform, got shape {X.shape}")
    R = X[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ScannerError(f"{name}: the rotation block is not a rotation matrix")
    return X


def snapped(X: np.ndarray, X_ref: np.ndarray, step: float = 1e-9) -> np.ndarray:
    """X with its difference from X_ref (rotation vector in rad, translation in m) rounded to
    multiples of `step`: two poses apart by rounding noise far below the step become the very
    same pose, unless they straddle a multiple (odds about noise / step per component)."""
    xi = pose_to_twist(invert(X_ref) @ X)
    return X_ref @ twist_to_pose(np.round(xi / step) * step)
