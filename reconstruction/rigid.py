"""Small rigid-transform helpers on 4x4 numpy arrays (monogram notation: X_AB is B in A)."""

from __future__ import annotations

import cv2
import numpy as np


def make_X(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = np.asarray(p, float).ravel()
    return X


def inverse(X_AB: np.ndarray) -> np.ndarray:
    """X_BA from X_AB without a general matrix inverse."""
    R = X_AB[:3, :3]
    return make_X(R.T, -R.T @ X_AB[:3, 3])


def rotation_from_rotvec(r: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(r, float).reshape(3, 1))[0]


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, float))[0].ravel()


def X_from_rvec_tvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """OpenCV (rvec, tvec) of an object O seen by camera C -> X_CO."""
    return make_X(rotation_from_rotvec(rvec), tvec)


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """A small pose from 6 numbers (rotation vector rad, translation m); first-order exp map."""
    return make_X(rotation_from_rotvec(xi[:3]), xi[3:])


def rotation_angle_rad(R: np.ndarray) -> float:
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def pose_error(X_est: np.ndarray, X_true: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error rad) between two poses of the same frame."""
    dt = float(np.linalg.norm(X_est[:3, 3] - X_true[:3, 3]))
    dr = rotation_angle_rad(X_est[:3, :3].T @ X_true[:3, :3])
    return dt, dr


def mean_pose(X_list: list[np.ndarray]) -> np.ndarray:
    """Chordal mean of rotations (projected back with SVD) and mean of translations."""
    Rs = np.array([X[:3, :3] for X in X_list])
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return make_X(R, np.mean([X[:3, 3] for X in X_list], axis=0))


def transform_points(X_AB: np.ndarray, p_B: np.ndarray) -> np.ndarray:
    """p_A (N, 3) of points p_B (N, 3)."""
    return p_B @ X_AB[:3, :3].T + X_AB[:3, 3]
