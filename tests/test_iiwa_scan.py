"""The iiwa 14 in a scan's cell, cheaply: its cell is built around its own flange (the simulated
camera renders from there), and views around an object in front of it are reached collision-free.
A whole simulated iiwa scan is scripts/bench_arms.py's (its numerical IK on a 7-axis grid makes
planning minutes long)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from planners.collision import CollisionChecker
from planners.config import PlannerConfig
from planners.ik import Viewpoint, camera_pose, ik_camera, rig_centre_offset
from robots.arms.default import arm_of
from robots.models.camera_tool import nominal_X_FC
from robots.models.workcell import WorkcellConfig, build_workcell
from scanner.configs.scan import ScanConfig

IIWA_FILE = str(
    Path(__file__).resolve().parents[1] / "scanner" / "configs" / "arms" / "iiwa14.yaml"
)
STEREO = ScanConfig().camera.stereo_camera()
X_FC = nominal_X_FC(STEREO.baseline_m)
# Where the reach search hangs a 0.2 m object for the iiwa at 0.5 m (planners/reach.py, the
# default grid: 25 % of the coarse sphere, its best candidate).
CENTER_M = (0.325, 0.0, 0.924)
# The camera's pose from the cell's flange frame agrees with the arm's FK to rounding.
POSE_TOL_M = 1e-9


def test_the_iiwa_cell_carries_its_own_flange_and_reaches_a_view_of_the_object():
    arm = arm_of(IIWA_FILE)
    cell = build_workcell(WorkcellConfig(object_center_m=CENTER_M), None, X_FC, STEREO.X_CR, arm)
    assert cell.flange_frame == arm.flange_frame == "iiwa_link_ee_kuka"
    plant = cell.plant
    context = plant.CreateDefaultContext()
    q = np.array(arm.home_q)
    plant.SetPositions(context, cell.robot, q)
    X_WF = plant.GetFrameByName(cell.flange_frame, cell.robot).CalcPoseInWorld(context)
    assert np.allclose(X_WF.GetAsMatrix4(), arm.X_WF(q).GetAsMatrix4(), atol=POSE_TOL_M)
    # A view from 0.5 m on the arm's side of the object, about level with it (one of the
    # directions the reach search found reachable there): the iiwa puts the camera there, and
    # not every solution collides with the cell.
    centre = np.array(CENTER_M)
    direction = np.array([-0.967, 0.239, 0.091]) / np.linalg.norm([-0.967, 0.239, 0.091])
    viewpoint = Viewpoint(tuple(centre + 0.5 * direction), CENTER_M, 0.0)
    X_WC = camera_pose(viewpoint, rig_centre_offset(STEREO.X_CR))
    solutions = ik_camera(arm, X_WC, X_FC, arm.home_q)
    assert len(solutions) > 0
    for q in solutions[:3]:
        X = arm.X_WF(q).GetAsMatrix4() @ X_FC
        assert np.allclose(X, X_WC, atol=1e-6)
    checker = CollisionChecker(cell, PlannerConfig().padding_m, PlannerConfig().edge_step_rad)
    assert checker.are_free(solutions).any()
