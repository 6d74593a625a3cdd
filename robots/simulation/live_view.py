"""Live Meshcat view of a simulated scan: the arm, the executed paths and the growing cloud."""

from __future__ import annotations

import time

import numpy as np

from robots.drivers.interfaces import JointTrajectory
from robots.models.workcell import Workcell

FRAME_S = 1 / 30


class LiveView:
    """Publishes the work cell (built with `meshcat=`) and draws on the same Meshcat."""

    def __init__(self, workcell: Workcell, meshcat, X_WF) -> None:
        self._cell = workcell
        self._meshcat = meshcat
        self._X_WF = X_WF
        self._context = workcell.diagram.CreateDefaultContext()
        self._paths = 0

    def show(self, q: np.ndarray) -> None:
        plant = self._cell.plant
        plant.SetPositions(plant.GetMyContextFromRoot(self._context), self._cell.robot, q)
        self._cell.diagram.ForcedPublish(self._context)

    def play(self, trajectory: JointTrajectory, true_offsets: np.ndarray) -> None:
        """Real-time playback; the flange path is drawn as a line that stays."""
        from pydrake.geometry import Rgba

        t, q = trajectory.times_s, trajectory.positions_rad
        frames = np.arange(0.0, trajectory.duration_s + FRAME_S, FRAME_S)
        path = np.stack([np.interp(frames, t, q[:, j]) for j in range(q.shape[1])], axis=1)
        points = np.array([self._X_WF(p)[:3, 3] for p in path]).T
        self._meshcat.SetLine(f"paths/{self._paths:03d}", points, 2.0, Rgba(0.1, 0.4, 0.9, 1))
        self._paths += 1
        for qk in path:
            self.show(qk + true_offsets)
            time.sleep(FRAME_S)

    def add_cloud(self, name: str, points_W: np.ndarray, colors: np.ndarray) -> None:
        from pydrake.perception import BaseField, Fields, PointCloud

        cloud = PointCloud(len(points_W), Fields(BaseField.kXYZs | BaseField.kRGBs))
        cloud.mutable_xyzs()[:] = points_W.T
        cloud.mutable_rgbs()[:] = colors.T
        self._meshcat.SetObject(f"clouds/{name}", cloud, point_size=0.002)
