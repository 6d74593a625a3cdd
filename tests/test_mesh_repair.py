"""Mesh repairs written in numpy agree with the Open3D routines they replace."""

import numpy as np
import open3d as o3d
import pytest

from reconstruction.surfaces.topology import (
    _edge_use,
    _manifold_edges_keep,
    clean_mesh,
    triangle_components,
)


def _two_spheres_and_a_fin():
    a = o3d.geometry.TriangleMesh.create_sphere(radius=0.01, resolution=10)
    b = o3d.geometry.TriangleMesh.create_sphere(radius=0.002, resolution=6).translate((0.05, 0, 0))
    mesh = a + b
    v = np.asarray(mesh.vertices)
    t = np.asarray(mesh.triangles)
    # A small fin on one edge of the big sphere: that edge is then used by three triangles.
    i, j = int(t[0, 0]), int(t[0, 1])
    fin_tip = (v[i] + v[j]) / 2 + np.array([0.0, 0.0, 1e-4])
    vertices = np.vstack([v, fin_tip])
    triangles = np.vstack([t, [i, j, len(v)]])
    return vertices, triangles


def test_components_match_open3d():
    vertices, triangles = _two_spheres_and_a_fin()
    labels, counts = triangle_components(triangles)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    o3d_labels, o3d_counts, _ = mesh.cluster_connected_triangles()
    assert sorted(counts.tolist()) == sorted(np.asarray(o3d_counts).tolist())
    # The same partition: each of our labels maps to exactly one of Open3D's.
    pairs = set(zip(labels.tolist(), np.asarray(o3d_labels).tolist()))
    assert len(pairs) == len(counts) == 2


def test_an_overused_edge_loses_its_smallest_triangle():
    vertices, triangles = _two_spheres_and_a_fin()
    assert (_edge_use(triangles).uses > 2).sum() == 1
    keep = _manifold_edges_keep(vertices, triangles)
    assert np.flatnonzero(~keep).tolist() == [len(triangles) - 1]  # the fin, the smallest
    assert (_edge_use(triangles[keep]).uses <= 2).all()


def test_clean_mesh_drops_debris_and_the_fin():
    vertices, triangles = _two_spheres_and_a_fin()
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    big = len(o3d.geometry.TriangleMesh.create_sphere(radius=0.01, resolution=10).triangles)
    clean_mesh(mesh, min_component_fraction=0.5)  # the small sphere is debris
    assert len(mesh.triangles) == big
    assert mesh.is_watertight()


def test_canonical_order_is_one_order_for_one_geometry_and_keeps_winding():
    from reconstruction.surfaces.topology import canonical_order

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=0.01, resolution=8)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(v))
    new_index = np.empty_like(perm)
    new_index[perm] = np.arange(len(perm))
    shuffled = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v[perm]),
        o3d.utility.Vector3iVector(new_index[t][rng.permutation(len(t))]),
    )
    a, b = canonical_order(sphere), canonical_order(shuffled)
    np.testing.assert_array_equal(np.asarray(a.vertices), np.asarray(b.vertices))
    np.testing.assert_array_equal(np.asarray(a.triangles), np.asarray(b.triangles))
    # Outward normals stay outward: the winding was turned, never flipped.
    a.compute_triangle_normals()
    centres = np.asarray(a.vertices)[np.asarray(a.triangles)].mean(axis=1)
    assert (np.einsum("ij,ij->i", np.asarray(a.triangle_normals), centres) > 0).all()


def test_the_edge_table_asked_again_is_the_same_triangles_table_never_a_stale_one():
    """Finishing a mesh asks for the edge table of the same triangles several times in a row:
    the last one is kept (per thread) and handed out read-only; triangles of the same shape
    that differ in one index get their own table."""
    import threading

    from reconstruction.surfaces.topology import _edge_table, _edge_use

    def same(a, b) -> bool:
        return all(
            np.array_equal(getattr(a, k), getattr(b, k)) for k in ("edges", "uses", "of_triangle")
        )

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.05, 20)
    triangles = np.asarray(sphere.triangles).copy()
    first = _edge_use(triangles)
    assert _edge_use(triangles.copy()) is first and same(first, _edge_table(triangles))
    with pytest.raises(ValueError):
        first.uses[0] = 3  # shared: nobody may change it
    other = triangles.copy()
    other[0, 2] = other[1, 2]  # the same shape, one corner moved
    assert same(_edge_use(other), _edge_table(other)) and not same(_edge_use(other), first)
    # Each thread keeps its own last table: two threads alternating two meshes get each right.
    box = np.asarray(o3d.geometry.TriangleMesh.create_box().triangles).copy()
    wrong = []

    def ask(mine):
        for _ in range(20):
            if not same(_edge_use(mine), _edge_table(mine)):
                wrong.append(mine)

    threads = [threading.Thread(target=ask, args=(t,)) for t in (triangles, box)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not wrong
