"""A static stereo camera in the cell (eye-to-hand): renders from a fixed true pose X_WS.

Same rendering, lens distortion and noise as the wrist camera (robots/sim_camera.py); the arm is
posed at its TRUE joint positions so the marker on its flange is where the real one would be.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.common.checks import integer, positive
from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose
from reconstruction.stereo.camera_model import StereoCamera, StereoDesign
from robots.models.workcell import Workcell
from robots.simulation.blinking_marker import BlinkingMarker
from robots.simulation.stereo_camera import SimulatedStereoCamera
from robots.simulation.truth import Truth


@dataclass(frozen=True)
class StaticCameraConfig(StereoDesign):
    """Where the static rig stands (rig centre, m) and the point it looks at (m), and
    its optics (a VGA machine-vision pair). A cell camera can afford a wider baseline than the
    wrist rig: 0.25 m keeps the depth error of a 0.05 px disparity error near 0.3 mm at 1 m
    (Z^2 / (f b))."""

    width_px: int = integer(640, minimum=16)
    height_px: int = integer(480, minimum=16)
    focal_px: float = positive(640.0)
    baseline_m: float = positive(0.25)
    distortion: tuple[float, float, float, float, float] = (-0.12, 0.05, 0.0, 0.0, 0.0)
    position_m: tuple[float, float, float] = (1.15, 0.35, 0.75)
    look_at_m: tuple[float, float, float] = (0.50, 0.05, 0.50)

    def __post_init__(self) -> None:
        super().__post_init__()
        if np.linalg.norm(np.subtract(self.look_at_m, self.position_m)) < 0.1:
            raise ScannerError("camera.look_at_m: expected at least 0.1 m from camera.position_m")

    @property
    def X_WS(self) -> np.ndarray:
        """Left optical frame S. The rig centre (midway between the lenses) sits at position_m
        and looks at look_at_m, image rows level: both cameras then see the target alike."""
        z = np.subtract(self.look_at_m, self.position_m)
        z = z / np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        if np.linalg.norm(x) < 1e-6:
            raise ScannerError("static camera: looking straight up or down is not supported")
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        return make_pose(R, np.asarray(self.position_m) - x * self.baseline_m / 2)


class StaticStereoCamera(SimulatedStereoCamera):
    """Renders from X_WS; `blink_frames` gives the frames of a blinking marker at rest."""

    def __init__(
        self,
        workcell: Workcell,
        truth: Truth,
        true_joint_positions,
        stereo: StereoCamera,
        X_WS: np.ndarray,
        marker: BlinkingMarker,
    ) -> None:
        super().__init__(workcell, dataclasses.replace(truth, stereo=stereo), true_joint_positions)
        self._X_WS = np.array(X_WS, float)
        self._marker = marker

    def true_X_WC(self) -> np.ndarray:
        plant = self._cell.plant
        plant.SetPositions(
            plant.GetMyContextFromRoot(self._context), self._cell.robot, self._true_q()
        )
        return self._X_WS

    def _pair(self, lit: bool) -> tuple[np.ndarray, np.ndarray]:
        sg = self._cell.scene_graph
        self._marker.set_lit(sg, sg.GetMyMutableContextFromRoot(self._context), lit)
        X_WS = self.true_X_WC()
        return self._render_rgb(self._left, X_WS), self._render_rgb(self._right, X_WS @ self._X_CR)

    def blink_frames(self, count: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """`count` consecutive grey left and right frames, the marker lit in every other one.

        The scene is still while the arm rests, so each state is rendered once and every frame
        gets its own sensor noise (what a camera filming a blinking LED records). Grey frames:
        the KTH set-up also ran its cameras in black and white (for the frame rate).
        """
        on = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in self._pair(True)]
        off = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in self._pair(False)]
        rng = np.random.default_rng([self._truth.seed, self._captures, 7])
        self._captures += 1
        std = np.float32(self._truth.image_noise_std)
        lefts, rights = [], []
        for k in range(count):
            state = on if k % 2 == 0 else off
            frames = []
            for image in state:
                noise = rng.standard_normal(image.shape, dtype=np.float32) * std
                frames.append(np.clip(image + noise, 0, 255).astype(np.uint8))
            lefts.append(frames[0])
            rights.append(frames[1])
        return lefts, rights
