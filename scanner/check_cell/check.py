"""The cell check: connect, read the controller's state, grab one pair, plan the first move, and
give a verdict per item without moving the arm.

Configuration errors (a host that does not answer, a port speaking another protocol, a camera
that does not open or delivers another size) stop the check as they stop a scan: one line, exit
2. Everything else is an item with a verdict; the cell can scan when every item passes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from planners.planner import PlanFailure
from reconstruction.calibration.boards import BoardSpec, detect_board
from robots.drivers.connect import close_all
from robots.drivers.interfaces import CaptureError, StereoImages
from scanner.configs.scan import ScanConfig
from scanner.scan.run import new_scan_views
from scanner.scan.world import ScanWorld, setup_world


@dataclass(frozen=True)
class ImageLimits:
    """What a usable image is. Exposure: the mean grey level (0-255) inside [min, max] and at
    most max_clipped_share of the pixels at 0 or 255 (SGBM finds nothing in clipped areas).
    Sharpness: the variance of the Laplacian of the grey image at least min_sharpness. It
    depends on the scene, so the bound only catches a camera far out of focus: measured on
    real images (OpenCV's stereo sample, Middlebury) 500-1500 sharp, 7-22 after a 2-px
    Gaussian blur, 2-4 after 4 px; the simulated cell's 1280x960 renders (mostly plain
    background) 38-57."""

    min_mean_grey: float = 25.0
    max_mean_grey: float = 230.0
    max_clipped_share: float = 0.05
    min_sharpness: float = 10.0


@dataclass(frozen=True)
class CheckItem:
    name: str
    ok: bool
    detail: str

    def line(self) -> str:
        return f"{'ok  ' if self.ok else 'FAIL'}  {self.name:<12} {self.detail}"


def exposure_item(side: str, image: np.ndarray, limits: ImageLimits) -> CheckItem:
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    mean = float(grey.mean())
    clipped = float(np.mean((grey == 0) | (grey == 255)))
    ok = limits.min_mean_grey <= mean <= limits.max_mean_grey and (
        clipped <= limits.max_clipped_share
    )
    detail = (
        f"{side}: mean grey {mean:.0f} (allowed {limits.min_mean_grey:.0f}-"
        f"{limits.max_mean_grey:.0f}), {100 * clipped:.1f} % clipped (allowed "
        f"{100 * limits.max_clipped_share:.0f} %)"
    )
    return CheckItem("exposure", ok, detail)


def sharpness_item(side: str, image: np.ndarray, limits: ImageLimits) -> CheckItem:
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    sharpness = float(cv2.Laplacian(grey, cv2.CV_64F).var())
    detail = f"{side}: Laplacian variance {sharpness:.0f} (at least {limits.min_sharpness:.0f})"
    return CheckItem("sharpness", sharpness >= limits.min_sharpness, detail)


def image_items(
    pair: StereoImages, limits: ImageLimits, board: BoardSpec | None
) -> list[CheckItem]:
    items = []
    for side, image in (("left", pair.left), ("right", pair.right)):
        items += [exposure_item(side, image, limits), sharpness_item(side, image, limits)]
    if board is not None:
        found = [detect_board(board, image) for image in (pair.left, pair.right)]
        counts = [0 if d is None else len(d) for d in found]
        ok = all(counts)
        items.append(
            CheckItem(
                "board",
                ok,
                f"{board.kind} {board.cols}x{board.rows}: {counts[0]} points left, "
                f"{counts[1]} right" + ("" if ok else " (the board must be seen by both)"),
            )
        )
    return items


def controller_items(world: ScanWorld) -> list[CheckItem]:
    robot = world.robot
    refusal = getattr(robot, "refusal", None)
    items = []
    if refusal is not None:
        why = refusal()
        items.append(CheckItem("controller", why is None, why or "ready: drives on, no e-stop"))
    q = robot.joint_positions()
    lower, upper = world.planner.arm.lower, world.planner.arm.upper
    outside = [f"J{i + 1}" for i in range(6) if not lower[i] <= q[i] <= upper[i]]
    joints = " ".join(f"{np.degrees(v):.1f}" for v in q)
    if outside:
        items.append(CheckItem("joints", False, f"{', '.join(outside)} outside the limits"))
    elif not world.planner.is_collision_free(q):
        items.append(
            CheckItem("joints", False, f"[{joints}] deg collides in the cell model (padded)")
        )
    else:
        items.append(CheckItem("joints", True, f"[{joints}] deg, within the limits, free"))
    return items


def first_move_item(config: ScanConfig, world: ScanWorld) -> CheckItem:
    """Plan (never execute) from the measured joints to the first view that can be reached,
    as the scan's first motion would be checked."""
    q = world.robot.joint_positions()
    plan, views = new_scan_views(config, world)
    if not views:
        return CheckItem("first move", False, "no viewpoint of the scan is reachable")
    failures = []
    for view in views[:3]:
        for option in view.options:
            result = world.planner.plan(q, option.q)
            if not isinstance(result, PlanFailure):
                result = world.planner.executable(result, world.robot.motion)
            if isinstance(result, PlanFailure):
                failures.append(result.reason)
                continue
            return CheckItem(
                "first move",
                True,
                f"to view {view.index}: {len(result.positions_rad) - 1} checked waypoints; "
                f"{len(views)} views reachable ({100 * plan.reachable_fraction:.0f} % of the "
                "directions)",
            )
    return CheckItem("first move", False, "no path to the first views: " + ", ".join(failures))


def check_cell(
    config: ScanConfig,
    board: BoardSpec | None = None,
    limits: ImageLimits = ImageLimits(),
    report: Callable[[CheckItem], None] = lambda item: None,
) -> list[CheckItem]:
    """Every item, reported as it is decided; the arm is never moved."""
    world = setup_world(config)
    items: list[CheckItem] = []

    def add(new: list[CheckItem]) -> None:
        for item in new:
            items.append(item)
            report(item)

    try:
        add([CheckItem("robot link", True, _link_words(config))])
        add(controller_items(world))
        try:
            pair = world.camera.capture()
        except CaptureError as e:
            add([CheckItem("camera", False, f"no pair: {e}")])
        else:
            w, h = world.camera_model.image_size
            add([CheckItem("camera", True, f"a pair of {w}x{h} images, as calibrated")])
            add(image_items(pair, limits, board))
        add([first_move_item(config, world)])
    finally:
        close_all(world.robot, world.camera)
    return items


def _link_words(config: ScanConfig) -> str:
    if config.hardware is None:
        return f"driver {config.driver}"
    r = config.hardware.robot
    return f"{r.kind} at {r.host}, ports {r.motion_port} and {r.state_port}: state streaming"
