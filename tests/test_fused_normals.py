"""The fused cloud's local planes (`fused_normals`): smoother normals, and the points off them."""

import numpy as np
import open3d as o3d

from reconstruction.surfaces.fused import FusedCloud, refine_fused
from reconstruction.surfaces.normals import local_planes, off_surface


def refined_normals(points, normals, radius_m):
    return local_planes(points, normals, radius_m).normals


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def _noisy(normals: np.ndarray, std_rad: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = normals + std_rad * rng.standard_normal(normals.shape)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _sphere(radius_m: float, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = rng.standard_normal((count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return radius_m * n, n


def test_noisy_normals_of_a_sphere_come_closer_to_the_truth():
    points, true_n = _sphere(0.02, 5000)  # ~1 mm spacing, like the fused cloud
    points = points + 5e-5 * np.random.default_rng(1).standard_normal(points.shape)
    noisy = _noisy(true_n, np.radians(8.0), seed=5)
    refined = refined_normals(points, noisy, 0.004)
    before = np.median(_angles_deg(noisy, true_n))
    after = np.median(_angles_deg(refined, true_n))
    assert before > 6.0
    assert after < 0.4 * before
    # Signed like the input: every normal still points out of the sphere.
    assert np.all(np.einsum("ij,ij->i", refined, true_n) > 0)
    np.testing.assert_allclose(np.linalg.norm(refined, axis=1), 1.0, atol=1e-9)


def _grid(size_m: float, step_m: float) -> np.ndarray:
    u = np.arange(-size_m / 2, size_m / 2 + 1e-12, step_m)
    return np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)


def test_the_two_sides_of_a_thin_wall_keep_their_own_normals():
    uv = _grid(0.03, 0.001)
    thickness = 0.0015  # thinner than the 4 mm radius
    front = np.column_stack([uv, np.full(len(uv), thickness / 2)])
    back = np.column_stack([uv, np.full(len(uv), -thickness / 2)])
    points = np.vstack([front, back])
    true_n = np.vstack([np.tile([0, 0, 1.0], (len(uv), 1)), np.tile([0, 0, -1.0], (len(uv), 1))])
    refined = refined_normals(points, _noisy(true_n, np.radians(5.0)), 0.004)
    assert np.percentile(_angles_deg(refined, true_n), 99) < 3.0


def test_the_faces_of_a_sharp_edge_keep_their_own_normals():
    # Two faces meeting at 90 deg along the y axis; every normal within 1 mm of the edge too.
    uv = _grid(0.03, 0.001)
    uv = uv[uv[:, 0] > 0]
    top = np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))])
    side = np.column_stack([np.zeros(len(uv)), uv[:, 1], -uv[:, 0]])
    points = np.vstack([top, side])
    true_n = np.vstack([np.tile([0, 0, 1.0], (len(uv), 1)), np.tile([-1.0, 0, 0], (len(uv), 1))])
    refined = refined_normals(points, _noisy(true_n, np.radians(5.0)), 0.004)
    assert np.max(_angles_deg(refined, true_n)) < 5.0


def test_points_without_enough_agreeing_neighbours_keep_their_normal():
    points = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.01, 0.01, 0], [0.02, 0, 0]])
    normals = _noisy(np.tile([0, 0, 1.0], (5, 1)), 0.2)
    np.testing.assert_array_equal(refined_normals(points, normals, 0.004), normals)
    np.testing.assert_array_equal(refined_normals(points, normals, 0.0), normals)


def test_poisson_from_refined_normals_is_smoother():
    # What the refinement is for: Poisson integrates the normals, so their noise becomes bumps.
    points, true_n = _sphere(0.02, 8000, seed=2)
    noisy = _noisy(true_n, np.radians(10.0), seed=3)

    def radial_rms_mm(normals: np.ndarray) -> float:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pc.normals = o3d.utility.Vector3dVector(normals)
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
                pc, depth=7, n_threads=1
            )
        r = np.linalg.norm(np.asarray(mesh.vertices), axis=1)
        return 1e3 * float(np.sqrt(np.mean((r - 0.02) ** 2)))

    noisy_rms = radial_rms_mm(noisy)
    refined_rms = radial_rms_mm(refined_normals(points, noisy, 0.004))
    assert refined_rms < 0.7 * noisy_rms


def test_points_off_the_local_surface_are_dropped_and_the_rest_kept():
    rng = np.random.default_rng(7)
    uv = _grid(0.04, 0.001)
    points = np.column_stack([uv, 1e-4 * rng.standard_normal(len(uv))])  # 0.1 mm noise
    lifted = rng.choice(len(points), 40, replace=False)
    points[lifted, 2] += 0.0015  # mismatches 1.5 mm off the surface
    normals = _noisy(np.tile([0, 0, 1.0], (len(points), 1)), np.radians(5.0), seed=8)
    planes = local_planes(points, normals, 0.004)
    # Residuals of the surface's own points are of the order of the noise.
    inliers = np.setdiff1d(np.arange(len(points)), lifted)
    assert np.median(planes.residuals_m[inliers]) < 1.5e-4
    off = off_surface(planes.residuals_m, 2.5)
    assert off[lifted].all()
    # A normal residual passes 2.5 sigma 1.2 % of the time; the lifted points tilt a few planes.
    assert off[inliers].mean() < 0.03
    assert not off_surface(planes.residuals_m, 0.0).any()

    colours = np.zeros((len(points), 3), np.uint8)
    colours[lifted] = 255
    fused = refine_fused(FusedCloud(points, colours, normals), 0.004, 2.5)
    assert len(fused) == len(points) - off.sum()
    assert not (fused.colors == 255).any()  # colours go with their points
    # From ~6 deg in; the lifted points tilt the planes near them a little.
    assert np.median(_angles_deg(fused.normals_W, np.tile([0, 0, 1.0], (len(fused), 1)))) < 2.0
    # Off: the cloud as it was.
    assert refine_fused(FusedCloud(points, colours, normals), 0.0, 2.5).points_W is points


def test_the_batches_on_several_threads_give_what_one_thread_gives(monkeypatch):
    """The batches run on a thread pool (each writes its own rows): a cloud of several
    batches gives the same normals and residuals bit for bit on one thread and on four, the
    sphere's truth holding either way."""
    import reconstruction.surfaces.normals as normals_module

    points, true_n = _sphere(0.05, 40_000, seed=3)  # five batches
    points = points + 5e-5 * np.random.default_rng(4).standard_normal(points.shape)
    noisy = _noisy(true_n, np.radians(8.0), seed=6)
    runs = {}
    for threads in (1, 4):
        monkeypatch.setattr(normals_module, "PLANE_THREADS", threads)
        runs[threads] = local_planes(points, noisy, 0.004)
    assert len(points) > 4 * normals_module.BATCH
    np.testing.assert_array_equal(runs[1].normals, runs[4].normals)
    np.testing.assert_array_equal(runs[1].residuals_m, runs[4].residuals_m)
    assert np.median(_angles_deg(runs[4].normals, true_n)) < 0.4 * np.median(
        _angles_deg(noisy, true_n)
    )
