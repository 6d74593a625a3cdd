"""model.html: a result as one self-contained 3D page (Drake's Meshcat viewer and the scene in a
single HTML file; no network, no server once written). Each layer has its own path in the
scene tree, so the viewer's controls switch it on and off:

    /model       the headline mesh, coloured per vertex on the deviation pictures' fixed scale
    /unseen      points of the true surface that no view saw (simulation only)
    /views       every view's camera frustum, coloured by hanging (/views/hanging_H/view_I)
    /fixture     the rods' axes
    /cell        the outlines of the cell's boxes (table, fence, ...)
    /robot       the arm and its camera tool at one pose
    /reference   the reference an inspection compared against (wireframe)
"""

from __future__ import annotations

import html
import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scanner.reports.deviation_picture import deviation_colours
from scanner.reports.model_page_layers import (
    DisplayMesh,
    ModelScene,
    RobotPose,
    box_segments,
    framing,
    frustum_segments,
)

PAGE_NAME = "model.html"
MODEL_PATH = "/model"
UNSEEN_PATH = "/unseen"
VIEWS_PATH = "/views"
FIXTURE_PATH = "/fixture"
CELL_PATH = "/cell"
ROBOT_PATH = "/robot"
REFERENCE_PATH = "/reference"

# Green is in no colour of the deviation map (blue-white-red), so the unseen parts stand out.
UNSEEN_RGBA = (0.1, 0.75, 0.2, 1.0)
FIXTURE_RGBA = (0.75, 0.75, 0.78, 1.0)
CELL_RGBA = (0.85, 0.8, 0.3, 1.0)
REFERENCE_RGBA = (0.6, 0.65, 0.7, 0.5)
# A dark background: the map's white (no deviation) must not vanish into Meshcat's white one.
BACKGROUND_TOP = (0.2, 0.22, 0.26)
BACKGROUND_BOTTOM = (0.05, 0.05, 0.07)
UNSEEN_POINT_SIZE_M = 0.001


@dataclass(frozen=True)
class ModelPage:
    """A written page: its file, size, the scene paths it holds, and the camera it opens with
    (p_WCamera looking at p_WTarget, Meshcat's default perspective camera)."""

    path: Path
    size_bytes: int
    layers: tuple[str, ...]
    p_WCamera: tuple[float, float, float]
    p_WTarget: tuple[float, float, float]


def hanging_rgb(hanging: int) -> tuple[float, float, float]:
    """The colour of a hanging (0-based): the hangings picture's."""
    import matplotlib.colors

    from scanner.reports.plots import PASS_COLOURS

    return matplotlib.colors.to_rgb(PASS_COLOURS[hanging % len(PASS_COLOURS)])


def mesh_colours(mesh: DisplayMesh, scale_m: float) -> np.ndarray:
    """Per vertex its RGB in [0, 1] on the fixed scale +-scale_m (the deviation pictures')."""
    return deviation_colours(mesh.values_m, scale_m)


@contextmanager
def _quiet_drake():
    """Drake logs every Meshcat's address at INFO; a page is not a viewer to connect to."""
    logger = logging.getLogger("drake")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


def _columns(a: np.ndarray, dtype=float) -> np.ndarray:
    return np.asfortranarray(np.asarray(a, dtype).reshape(-1, 3).T)


def _rgba(rgba):
    from pydrake.geometry import Rgba

    return Rgba(*rgba)


def _draw_mesh(meshcat, path: str, mesh: DisplayMesh, colours: np.ndarray) -> None:
    meshcat.SetTriangleColorMesh(
        path,
        _columns(mesh.vertices_W),
        _columns(mesh.triangles, np.int32),
        _columns(colours),
    )


def _draw_segments(meshcat, path: str, start, end, rgba) -> None:
    meshcat.SetLineSegments(path, _columns(start), _columns(end), 1.0, _rgba(rgba))


def _draw_robot(meshcat, cell, robot: RobotPose) -> None:
    """The arm and its tool (not the cell's boxes: they are outlined in /cell) at `robot.q_rad`,
    published once through Drake's MeshcatVisualizer."""
    from robots.arms.default import arm_of
    from robots.models.workcell import WorkcellConfig, build_workcell

    bare = replace(cell or WorkcellConfig(), boxes=())
    workcell = build_workcell(
        bare,
        None,
        robot.X_FC,
        robot.X_CR,
        arm_of(robot.robot),
        meshcat=meshcat,
        include_object=False,
        meshcat_prefix=ROBOT_PATH,
    )
    context = workcell.diagram.CreateDefaultContext()
    plant_context = workcell.plant.GetMyMutableContextFromRoot(context)
    workcell.plant.SetPositions(plant_context, workcell.robot, np.asarray(robot.q_rad, float))
    workcell.diagram.ForcedPublish(context)


def _draw(meshcat, scene: ModelScene) -> list[str]:
    """Every layer of `scene` into `meshcat`; the paths drawn."""
    layers = [MODEL_PATH]
    _draw_mesh(meshcat, f"{MODEL_PATH}/mesh", scene.mesh, mesh_colours(scene.mesh, scene.scale_m))
    if scene.unseen_W is not None and len(scene.unseen_W):
        from pydrake.perception import BaseField, Fields, PointCloud

        cloud = PointCloud(len(scene.unseen_W), Fields(BaseField.kXYZs))
        cloud.mutable_xyzs()[:] = _columns(scene.unseen_W, np.float32)
        meshcat.SetObject(f"{UNSEEN_PATH}/points", cloud, UNSEEN_POINT_SIZE_M, _rgba(UNSEEN_RGBA))
        layers.append(UNSEEN_PATH)
    if scene.frustums and scene.camera is not None:
        for k, view in enumerate(scene.frustums):
            start, end = frustum_segments(view.X_WC, scene.camera)
            path = f"{VIEWS_PATH}/hanging_{view.hanging + 1}/view_{k + 1}"
            _draw_segments(meshcat, path, start, end, (*hanging_rgb(view.hanging), 1.0))
        layers.append(VIEWS_PATH)
    if scene.fixture_segments:
        start = np.array([s for s, _ in scene.fixture_segments])
        end = np.array([e for _, e in scene.fixture_segments])
        _draw_segments(meshcat, f"{FIXTURE_PATH}/axes", start, end, FIXTURE_RGBA)
        layers.append(FIXTURE_PATH)
    if scene.cell is not None and scene.cell.boxes:
        for box in scene.cell.boxes:
            start, end = box_segments(np.array(box.p_WB), np.array(box.size))
            _draw_segments(meshcat, f"{CELL_PATH}/{box.name}", start, end, CELL_RGBA)
        layers.append(CELL_PATH)
    if scene.robot is not None:
        _draw_robot(meshcat, scene.cell, scene.robot)
        layers.append(ROBOT_PATH)
    if scene.reference is not None:
        from pydrake.geometry import Meshcat

        meshcat.SetTriangleMesh(
            f"{REFERENCE_PATH}/mesh",
            _columns(scene.reference.vertices_W),
            _columns(scene.reference.triangles, np.int32),
            _rgba(REFERENCE_RGBA),
            wireframe=True,
            side=Meshcat.SideOfFaceToRender.kDoubleSide,
        )
        layers.append(REFERENCE_PATH)
    return layers


def _legend(scene: ModelScene, views: int) -> str:
    """A fixed caption at the page's bottom left: what the colours mean."""
    scale_mm = 1e3 * scene.scale_m
    if scene.signed:
        scale = f"scale +-{scale_mm:g} mm (blue inside, white on it, red outside)"
    else:
        scale = f"white 0 mm to red {scale_mm:g} mm or more"
    lines = [f"{scene.colour_meaning}; {scale}"]
    if scene.unseen_W is not None and len(scene.unseen_W):
        lines.append("green points: the true surface no view saw")
    if views:
        lines.append(f"{views} camera frustums, coloured by hanging")
    text = "<br>".join(html.escape(line) for line in lines)
    return (
        '<div id="scanner-legend" style="position:fixed;left:8px;bottom:8px;padding:4px 8px;'
        "font:12px sans-serif;color:#eee;background:rgba(0,0,0,0.5);"
        f'pointer-events:none">{text}</div>\n'
    )


def page_html(scene: ModelScene, title: str) -> tuple[str, list[str], tuple]:
    """The page's text, its layers and its camera (p_WCamera, p_WTarget)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    # localhost: the page is built in this process and never served. The port is the first
    # free one from 7000, so a live --meshcat viewer of the same process keeps its own.
    with _quiet_drake():
        meshcat = Meshcat(MeshcatParams(host="localhost"))
    layers = _draw(meshcat, scene)
    p_WCamera, p_WTarget = framing(scene.mesh.vertices_W)
    meshcat.SetCameraPose(p_WCamera, p_WTarget)
    meshcat.SetProperty("/Background", "top_color", list(BACKGROUND_TOP))
    meshcat.SetProperty("/Background", "bottom_color", list(BACKGROUND_BOTTOM))
    # The floor grid lies at the table's top, a metre below the object: it only clutters.
    meshcat.SetProperty("/Grid", "visible", False)
    text = meshcat.StaticHtml()
    text = text.replace("<title>Drake MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)
    head, tail = text.rsplit("</body>", 1)
    text = head + _legend(scene, len(scene.frustums)) + "</body>" + tail
    return text, layers, (p_WCamera, p_WTarget)


def write_model_page(scene: ModelScene, path: Path, title: str = "scanner model") -> ModelPage:
    """The scene as one self-contained HTML page at `path` (written whole or not at all:
    a hidden file renamed when complete)."""
    text, layers, (p_WCamera, p_WTarget) = page_html(scene, title)
    path = Path(path)
    partial = path.with_name(f".{path.name}.tmp")
    try:
        partial.write_text(text)
        os.replace(partial, path)
    except OSError:
        partial.unlink(missing_ok=True)
        raise
    return ModelPage(
        path,
        path.stat().st_size,
        tuple(layers),
        tuple(map(float, p_WCamera)),
        tuple(map(float, p_WTarget)),
    )
