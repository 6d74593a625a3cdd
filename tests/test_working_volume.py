"""The working volume of a recording (masks, the cameras' common view) and the table found in
the data: synthetic scenes whose answers are known."""

import math

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import make_pose
from reconstruction.working_volume.table import TableConfig, above_table, find_table
from reconstruction.working_volume.volume import (
    PosedCamera,
    WorkingVolume,
    common_view_centre,
    volume_from_common_view,
    volume_from_masks,
    volume_of_box,
)

CENTRE = np.array([0.1, -0.05, 0.6])
K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])


def _looking_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), eye)


def _ring(n: int = 8, distance: float = 0.5, elevation_deg: float = 30.0) -> list[PosedCamera]:
    cams = []
    e = math.radians(elevation_deg)
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = CENTRE + distance * np.array(
            [math.cos(a) * math.cos(e), math.sin(a) * math.cos(e), math.sin(e)]
        )
        cams.append(PosedCamera(K, _looking_at(eye, CENTRE), 320, 240))
    return cams


def _sphere_mask(cam: PosedCamera, centre: np.ndarray, radius: float) -> np.ndarray:
    v, u = np.mgrid[0 : cam.height, 0 : cam.width] + 0.5
    rays_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays_W = rays_C @ cam.X_WC[:3, :3].T
    rays_W /= np.linalg.norm(rays_W, axis=-1, keepdims=True)
    to_centre = centre - cam.X_WC[:3, 3]
    along = rays_W @ to_centre
    miss = np.linalg.norm(to_centre) ** 2 - along**2
    return ((miss <= radius**2) & (along > 0)).astype(np.uint8) * 255


def test_the_common_view_is_the_point_every_axis_passes():
    cams = _ring()
    np.testing.assert_allclose(common_view_centre(cams), CENTRE, atol=1e-9)
    volume = volume_from_common_view(cams)
    # The half-diagonal (200 px) at 0.5 m and 400 px focal length: 0.25 m.
    assert volume.radius_m == pytest.approx(0.5 * 200 / 400, rel=1e-6)
    assert volume.source == "common view"


def test_parallel_axes_have_no_common_view():
    cams = [PosedCamera(K, make_pose(np.eye(3), [x, 0, 0]), 320, 240) for x in (0.0, 0.1)]
    with pytest.raises(ScannerError, match="parallel"):
        common_view_centre(cams)


def test_the_masks_hull_holds_the_object_and_little_more():
    cams = _ring()
    centre, radius = CENTRE + [0.02, 0.01, -0.01], 0.04
    masks = [_sphere_mask(c, centre, radius) for c in cams]
    search = volume_from_common_view(cams)
    volume = volume_from_masks(cams, masks, search)
    cell = 2 * search.radius_m / 48
    # A sphere's visual hull from eight views around it and one elevation is barely larger.
    assert np.linalg.norm(volume.centre_W - centre) < 2 * cell
    assert radius <= volume.radius_m <= 1.25 * radius + 2 * cell
    with pytest.raises(ScannerError, match="3 masks for 8 cameras"):
        volume_from_masks(cams, masks[:3], search)
    empty = [np.zeros_like(m) for m in masks]
    with pytest.raises(ScannerError, match="inside every mask"):
        volume_from_masks(cams, empty, search)
    with pytest.raises(ScannerError, match="radius"):
        WorkingVolume(CENTRE, 0.0, "given")


def _table_scene(rng, wall: bool):
    table = np.column_stack([rng.uniform(-0.3, 0.3, (6000, 2)), rng.normal(0, 3e-4, 6000)])
    box = rng.uniform([-0.05, -0.05, 0.0], [0.05, 0.05, 0.1], (3000, 3))
    parts = [table, box]
    if wall:  # a large front face of the object at y = -0.05, the rest of it behind
        wall_points = np.column_stack(
            [rng.uniform(-0.15, 0.15, 5000), np.full(5000, -0.05), rng.uniform(0.0, 0.2, 5000)]
        )
        behind = rng.uniform([-0.15, -0.05, 0.0], [0.15, 0.1, 0.2], (3000, 3))
        parts = [table[:1500], wall_points, behind]
    return np.concatenate(parts)


@pytest.mark.parametrize("wall", [False, True])
def test_the_table_is_the_plane_that_carries_the_object(wall):
    rng = np.random.default_rng(0)
    points = _table_scene(rng, wall)
    cameras = [np.array([0.0, -0.6, 0.5]), np.array([0.3, -0.5, 0.4]), np.array([-0.3, -0.5, 0.6])]
    table = find_table(points, cameras, TableConfig(min_share=0.05))
    assert table is not None
    # The table (z = 0, normal up), not the wall the cameras face (y = -0.05).
    assert table.normal_W @ [0, 0, 1] > 0.999 and abs(table.offset_m) < 1e-3
    keep = above_table(points, table, 0.003)
    assert not keep[np.abs(points[:, 2]) < 1e-3].any()
    assert keep[points[:, 2] > 0.01].all()


def test_an_object_without_a_table_has_none():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(5000, 3))
    sphere = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True)
    assert find_table(sphere, [np.array([0.0, 0.0, 0.5])]) is None


def test_a_box_is_its_centre_half_extents_and_the_sphere_around_it():
    volume = volume_of_box((-0.1, 0.0, 0.5), (0.1, 0.2, 0.8))
    np.testing.assert_allclose(volume.centre_W, [0.0, 0.1, 0.65])
    np.testing.assert_allclose(volume.half_extent_m, [0.1, 0.1, 0.15])
    # The sphere through the box's corners: what the depth windows and crops follow.
    assert volume.radius_m == pytest.approx(math.sqrt(0.1**2 + 0.1**2 + 0.15**2))
    assert volume.source == "given box"


@pytest.mark.parametrize(
    ("lo", "hi", "needle"),
    [
        ((0, 0, 0), (1, 1, 0), "must exceed its first"),
        ((0, 0, 0), (1, -1, 1), "must exceed its first"),
        ((0, 0, math.nan), (1, 1, 1), "three finite numbers"),
        ((0, 0), (1, 1, 1), "three finite numbers"),
    ],
)
def test_a_box_with_bad_corners_is_refused(lo, hi, needle):
    with pytest.raises(ScannerError, match=needle) as error:
        volume_of_box(lo, hi)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    ("fields", "needle"),
    [
        (
            {
                "volume_box_m": (0, 0, 0, 1, 1, 1),
                "volume_centre_m": (0, 0, 0),
                "volume_radius_m": 1,
            },
            "give a box or a sphere",
        ),
        ({"volume_box_m": (0, 0, 0, 1, 1)}, "six finite numbers"),
        ({"volume_box_m": (0, 0, 0, 1, 0, 1)}, "each maximum must exceed its minimum"),
    ],
)
def test_recording_settings_refuse_a_bad_box(fields, needle):
    from scanner.recordings.settings import RecordingProcessing

    with pytest.raises(ScannerError, match=f"recording.volume_box_m: .*{needle}"):
        RecordingProcessing(**fields)
