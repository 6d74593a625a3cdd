"""Built-in objects, mesh loading and bad input."""

import numpy as np
import pytest

from reconstruction.common.errors import ScannerError
from robots.models.objects import (
    BUILTIN_OBJECTS,
    find_named_mesh,
    resolve_object,
    write_textured_obj,
)
from tests.conftest import shared_data


@pytest.mark.parametrize("name", sorted(BUILTIN_OBJECTS))
def test_builtin_objects_are_closed_and_sized(name):
    import open3d as o3d

    mesh = resolve_object(name, 0.2)
    assert mesh.extent_m.max() == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_allclose((mesh.vertices.max(0) + mesh.vertices.min(0)) / 2, 0, atol=1e-9)
    o3 = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.array(mesh.vertices)),
        o3d.utility.Vector3iVector(np.array(mesh.triangles)),
    )
    assert o3.is_watertight()
    assert o3.get_volume() > 0


def test_bracket_has_holes():
    mesh = resolve_object("bracket", 0.2)
    t = mesh.triangles
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    v, e, f = len(mesh.vertices), len(np.unique(edges, axis=0)), len(t)
    # Euler characteristic V - E + F = 2 - 2 genus; four through holes give genus 4.
    assert 2 - (v - e + f) == 2 * 4


def test_textured_obj_has_normals_and_uvs(tmp_path):
    mesh = resolve_object("pebble", 0.1)
    path = write_textured_obj(mesh, tmp_path, texture_seed=1)
    text = path.read_text()
    assert (
        "\nvn " in text
        and "\nvt " in text
        and "map_Kd texture.png" in (tmp_path / "object.mtl").read_text()
    )
    face = next(line for line in text.splitlines() if line.startswith("f "))
    assert len(face.split()[1].split("/")) == 3


def test_shared_mesh_rescaled(tmp_path):
    path = shared_data("meshes/stanford-bunny.obj")
    mesh = resolve_object(str(path), 0.15)
    assert mesh.extent_m.max() == pytest.approx(0.15, abs=1e-9)


@pytest.mark.parametrize(
    "spec, size, message",
    [
        ("teacup", 0.2, "unknown object 'teacup'"),
        ("vase", 0.0, "positive"),
        ("vase", -1.0, "positive"),
        ("missing.obj", 0.2, "no such mesh file"),
    ],
)
def test_bad_object_input(spec, size, message):
    with pytest.raises(ScannerError, match=message):
        resolve_object(spec, size)


def test_empty_and_nan_meshes(tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(ScannerError, match="empty"):
        resolve_object(str(empty), 0.2)
    nan = tmp_path / "nan.obj"
    nan.write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nv 1 1 1\n"
        "f 1 2 3\nf 1 2 4\nf 2 3 4\nf 1 3 4\nf 2 3 5\n"
    )
    with pytest.raises(ScannerError, match="NaN"):
        resolve_object(str(nan), 0.2)


def _tetrahedron(path, scale):
    v = scale * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    faces = "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v) + faces)


def test_named_mesh_from_the_mesh_path(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    _tetrahedron(a / "stanford-bunny.obj", 1.0)
    _tetrahedron(b / "spot.obj", 2.0)
    _tetrahedron(b / "spot_old.obj", 3.0)
    monkeypatch.setenv("SCANNER_MESH_PATH", f"{a}:{b}:{tmp_path / 'missing'}")
    mesh = resolve_object("bunny", 0.1)  # a word of the file's stem
    assert mesh.extent_m.max() == pytest.approx(0.1, abs=1e-9)
    assert find_named_mesh("spot") == b / "spot.obj"  # the exact stem wins over spot_old
    _tetrahedron(b / "bunny-v2.obj", 1.0)
    with pytest.raises(ScannerError, match="ambiguous"):
        resolve_object("bunny", 0.1)
    with pytest.raises(ScannerError, match="SCANNER_MESH_PATH"):
        resolve_object("teacup", 0.1)
    assert resolve_object("vase", 0.1).extent_m.max() == pytest.approx(0.1, abs=1e-6)


def test_the_collision_hull_beside_the_obj_is_drakes_hull_of_the_mesh(tmp_path, vase_sim):
    from pydrake.geometry import Convex, Mesh, Role

    from robots.models.objects import collision_hull_path

    mesh = resolve_object("pebble", 0.2)
    obj = write_textured_obj(mesh, tmp_path, texture_seed=1)
    hull = collision_hull_path(obj)
    assert hull.is_file()

    def vertices(surface) -> set:
        return {tuple(np.round(surface.vertex(i), 9)) for i in range(surface.num_vertices())}

    assert vertices(Convex(str(hull)).GetConvexHull()) == vertices(Mesh(str(obj)).GetConvexHull())
    # The simulated cell registers that hull as the object's collision shape.
    inspector = vase_sim.workcell.scene_graph.model_inspector()
    shapes = [
        inspector.GetShape(g)
        for g in inspector.GetAllGeometryIds(Role.kProximity)
        if inspector.GetName(g).endswith("object_collision")
    ]
    assert len(shapes) == 1 and isinstance(shapes[0], Convex)
    assert str(shapes[0].source().path()).endswith("collision_hull.obj")
