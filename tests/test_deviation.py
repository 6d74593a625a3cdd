"""Signed deviations, their statistics, and the deviation picture's fixed colour scale."""

import numpy as np
import open3d as o3d
import pytest

from reconstruction.evaluation.deviation import deviation_stats, signed_distances
from reconstruction.evaluation.metrics import TriangleSurface
from scanner.reports.deviation_picture import colour_map_rgb, deviation_colours, scale_position
from scanner.reports.mesh_render import render_mesh


def _box(size=0.1) -> TriangleSurface:
    box = o3d.geometry.TriangleMesh.create_box(size, size, size)
    box.translate((0.4, -0.1, 0.9))  # away from the origin, like a model in the robot's frame
    return TriangleSurface(np.asarray(box.vertices), np.asarray(box.triangles))


def test_signed_distance_is_positive_outside_and_negative_inside():
    box = _box()
    centre = box.vertices.mean(axis=0)
    # On the +x face's centre line, 0.3 mm and 2 mm outside, 0.3 mm and 2 mm inside.
    offsets = np.array([0.0003, 0.002, -0.0003, -0.002])
    points = np.array([[centre[0] + 0.05 + o, centre[1] + 0.01, centre[2] - 0.02] for o in offsets])
    assert signed_distances(points, box) == pytest.approx(offsets, abs=2e-7)


def test_statistics_of_known_deviations():
    d = np.array([-0.002, -0.0004, 0.0, 0.0001, 0.0003, 0.0006, 0.001])
    s = deviation_stats(d, tolerance_m=0.0005)
    assert s.points == 7
    assert s.mean_m == pytest.approx(d.mean())
    assert s.rms_m == pytest.approx(np.sqrt(np.mean(d**2)))
    assert s.max_abs_m == pytest.approx(0.002)
    assert s.within_tolerance == pytest.approx(4 / 7)
    assert s.p90_abs_m == pytest.approx(np.percentile(np.abs(d), 90))
    report = s.as_report()
    assert report["rms_mm"] == pytest.approx(1e3 * s.rms_m) and report["tolerance_mm"] == 0.5


def test_the_colour_scale_is_fixed_and_saturates():
    scale = 0.001
    assert scale_position(np.array([-scale, 0.0, scale, 5 * scale]), scale) == pytest.approx(
        [0.0, 0.5, 1.0, 1.0]
    )
    rgb = colour_map_rgb()
    # The map's ends: blue for inside, red for outside; the middle near white.
    assert rgb[0, 2] > rgb[0, 0] + 50 and rgb[-1, 0] > rgb[-1, 2] + 50
    assert rgb[len(rgb) // 2].min() > 200
    # The same deviation gets the same colour whatever else the mesh holds.
    a = deviation_colours(np.array([0.0004, 0.0]), scale)[0]
    b = deviation_colours(np.array([0.0004, 0.01, -0.02]), scale)[0]
    assert np.array_equal(a, b)


def _rendered_centre(value01: float) -> np.ndarray:
    box = _box()
    (image,) = render_mesh(
        box.vertices,
        box.triangles,
        size_px=96,
        directions=[np.array([-1.0, -0.6, -0.4])],
        values01=np.full(len(box.vertices), value01),
        colour_map=colour_map_rgb(),
    )
    return image[40:56, 40:56].reshape(-1, 3).astype(float).mean(axis=0)


def test_rendered_mesh_takes_the_colour_of_its_deviation():
    outside, inside, on = _rendered_centre(1.0), _rendered_centre(0.0), _rendered_centre(0.5)
    assert outside[0] > outside[2] + 40  # red
    assert inside[2] > inside[0] + 40  # blue
    assert abs(on[0] - on[2]) < 25  # grey-white: lit, but neither red nor blue


def test_a_rendered_picture_frees_its_renderer_in_the_thread_that_drew_it():
    """Nothing of the renderer is left for the garbage collector: a GL context destroyed by a
    collection in another thread (the pictures are drawn beside other work) aborted a process."""
    import gc
    import threading

    from pydrake.geometry import SceneGraph
    from pydrake.systems.framework import System

    def renderers() -> int:
        return sum(isinstance(o, SceneGraph | System) for o in gc.get_objects())

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.05)
    images = []
    gc.collect()
    gc.disable()
    try:
        before = renderers()  # those other tests of this process keep alive
        drawing = threading.Thread(
            target=lambda: images.extend(
                render_mesh(np.asarray(sphere.vertices), np.asarray(sphere.triangles), 48)
            )
        )
        drawing.start()
        drawing.join()
        left = renderers() - before
    finally:
        gc.enable()
    assert images and images[0].max() > 0
    assert left == 0
