"""Points on the robot, tool, rod and cell are removed; points on the object are kept."""

import numpy as np

from robots.models.camera_tool import nominal_X_FC
from robots.models.kinematics import Kinematics
from robots.models.point_filter import _bounding_radius, _signed_distance, make_geometry_filter
from robots.models.workcell import WorkcellConfig, build_workcell, keep_out_radius_m


def test_primitive_distances():
    p = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.5, 0], [0, 0, 2]], float)
    np.testing.assert_allclose(_signed_distance("sphere", (0.5,), p)[:2], [-0.5, 0.5])
    np.testing.assert_allclose(_signed_distance("box", (1, 1, 1), p), [-0.5, 0.5, 0, 1.5])
    np.testing.assert_allclose(
        _signed_distance("cylinder", (0.5, 2.0), p)[[0, 1, 3]], [-0.5, 0.5, 1.0]
    )


def test_bounding_radius_encloses_each_primitive():
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(2000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for kind, size in (
        ("sphere", (0.05,)),
        ("box", (0.3, 0.1, 0.02)),
        ("cylinder", (0.04, 0.5)),
        ("capsule", (0.03, 0.2)),
    ):
        r = _bounding_radius(kind, size)
        # Every point on the bounding sphere is outside (or on) the primitive ...
        assert (_signed_distance(kind, size, r * directions) >= -1e-12).all(), kind
        # ... and the sphere is not needlessly loose along some direction.
        assert _signed_distance(kind, size, r * directions).min() < 0.01 * r, kind


def test_filter_removes_cell_and_robot_keeps_object():
    config = WorkcellConfig()
    cell = build_workcell(config, None, nominal_X_FC(), np.eye(4))
    keep = make_geometry_filter(cell, margin_m=0.01)
    q = np.array([0.0, -0.4, 2.3, 0.0, 0.8, 0.0])
    X_WF = Kinematics().X_WF(q)
    rng = np.random.default_rng(0)
    c = np.array(config.object_center_m)
    on_object = c + rng.normal(size=(500, 3)) * 0.03
    on_object[:, 2] = np.minimum(on_object[:, 2], c[2] - 0.02)  # the rod line: above the centre
    table = np.column_stack(
        [rng.uniform(-0.3, 0.6, 200), rng.uniform(-0.4, 0.4, 200), np.full(200, 0.001)]
    )
    rod = np.column_stack(
        [
            np.full(50, c[0]),
            np.full(50, c[1]),
            np.linspace(c[2] + keep_out_radius_m(config) + 0.05, 1.7, 50),
        ]
    )
    tool = X_WF[:3, :3] @ np.array([0.0, 0.0, 0.05]) + X_WF[:3, 3]
    assert keep(on_object, q).all()
    assert not keep(table, q).any()
    assert not keep(rod, q).any()
    assert not keep(tool[None], q).any()


def test_the_rod_is_removed_down_to_the_object():
    config = WorkcellConfig()
    cell = build_workcell(config, None, nominal_X_FC(), np.eye(4))
    keep = make_geometry_filter(cell, margin_m=0.01)
    c = np.array(config.object_center_m)
    # Just above a 0.2 m object's top: below the planner's keep-out sphere top, still rod.
    rod = np.column_stack(
        [np.full(20, c[0] + 0.003), np.full(20, c[1]), np.linspace(c[2] + 0.1, c[2] + 0.17, 20)]
    )
    beside = rod + np.array([0.05, 0.0, 0.0])
    assert not keep(rod, np.zeros(6)).any()
    assert keep(beside, np.zeros(6)).all()


def test_objects_hang_from_the_vertical_through_their_centre():
    from robots.models.objects import resolve_object
    from robots.models.workcell import placed_object

    for name in ("vase", "pebble", "bracket"):
        mesh = resolve_object(name, 0.2)
        p_OA = placed_object("x.obj", np.array(mesh.vertices), np.array(mesh.triangles)).p_OA
        if name != "bracket":  # the bracket's vertical through its centre meets its base plate
            np.testing.assert_allclose(p_OA[:2], 0.0, atol=1e-9)
        assert p_OA[2] <= mesh.vertices[:, 2].max() + 1e-6  # float32 ray casting


def test_a_point_is_judged_alike_whatever_cloud_it_comes_in():
    """The filter skips the primitives out of reach of the whole cloud: a cloud's mask is its
    parts' masks, whether the parts lie near the arm or far from it, and from two threads."""
    from concurrent.futures import ThreadPoolExecutor

    config = WorkcellConfig()
    keep = make_geometry_filter(build_workcell(config, None, nominal_X_FC(), np.eye(4)), 0.01)
    q = np.array([0.0, -0.4, 2.3, 0.0, 0.8, 0.0])
    rng = np.random.default_rng(2)
    # From the object out to the arm and the floor: some points near every primitive.
    cloud = np.array(config.object_center_m) + rng.normal(size=(6000, 3)) * [0.3, 0.3, 0.4]
    whole = keep(cloud, q)
    assert 0 < whole.sum() < len(whole)
    parts = np.array_split(np.arange(len(cloud)), 12)
    with ThreadPoolExecutor(2) as pool:
        masks = list(pool.map(lambda idx: keep(cloud[idx], q), parts))
    np.testing.assert_array_equal(np.concatenate(masks), whole)
    one_by_one = np.array([keep(p[None], q)[0] for p in cloud[:400]])
    np.testing.assert_array_equal(one_by_one, whole[:400])
    assert keep(np.zeros((0, 3)), q).shape == (0,)
