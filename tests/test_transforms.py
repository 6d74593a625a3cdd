"""The one pose/rotation module: round trips, precision near zero, and agreement with scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reconstruction.common.transforms import (
    invert,
    make_pose,
    matrix_to_rotvec,
    mean_pose,
    pose_difference,
    pose_to_twist,
    rotation_about,
    rotation_angle_rad,
    rotation_angles_rad,
    rotvec_to_matrix,
    transform_points,
    twist_to_pose,
)

ROTATIONS = Rotation.random(200, random_state=7)


def test_rotation_vectors_agree_with_scipy_and_round_trip():
    for rotvec in ROTATIONS.as_rotvec():
        R = rotvec_to_matrix(rotvec)
        assert np.allclose(R, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
        assert np.allclose(matrix_to_rotvec(R), rotvec, atol=1e-9)


@pytest.mark.parametrize("angle", [1e-9, 1e-6, 1e-3, 1.0, 3.1])
def test_rotation_angle_is_precise_at_every_size(angle):
    # arccos((trace - 1) / 2) returns ~2e-8 rad for any angle below that: no use for
    # convergence tests at 1e-5 rad.
    R = rotation_about([0.3, -0.5, 0.8], angle)
    assert rotation_angle_rad(R) == pytest.approx(angle, rel=1e-6)
    assert rotation_angles_rad(R[None], np.eye(3))[0] == pytest.approx(angle, rel=1e-6)


def test_poses_invert_compose_and_compare():
    X_AB = make_pose(ROTATIONS[0].as_matrix(), [0.1, -0.2, 0.3])
    p_B = np.random.default_rng(0).normal(size=(10, 3))
    assert np.allclose(transform_points(invert(X_AB), transform_points(X_AB, p_B)), p_B)
    xi = np.array([0.01, -0.02, 0.03, 0.004, 0.005, -0.006])
    assert np.allclose(pose_to_twist(twist_to_pose(xi)), xi, atol=1e-12)
    moved = X_AB @ twist_to_pose(xi)
    dt, dr = pose_difference(X_AB, moved)
    assert dr == pytest.approx(np.linalg.norm(xi[:3]), rel=1e-9)
    assert dt == pytest.approx(np.linalg.norm(X_AB[:3, :3] @ xi[3:]), rel=1e-9)


def test_mean_pose_of_small_perturbations_is_the_centre():
    X = make_pose(ROTATIONS[1].as_matrix(), [0.4, 0.0, 1.0])
    rng = np.random.default_rng(1)
    twists = rng.normal(scale=[0.01] * 3 + [0.002] * 3, size=(40, 6))
    around = [X @ twist_to_pose(t) for t in np.vstack([twists, -twists])]
    dt, dr = pose_difference(mean_pose(around), X)
    assert dt < 1e-12 and dr < 1e-4  # symmetric set: the chordal mean is the centre
