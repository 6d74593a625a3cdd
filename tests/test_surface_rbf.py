"""RBF implicit surface (reconstruction/surface_rbf.py) on a noisy spherical cap with known truth:
it lies on the sphere, covers the cap and no more, faces out, is deterministic, and bad
settings are refused with the field's name."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from reconstruction.common.errors import ScannerError
from reconstruction.surfaces.build import build_surface, rbf_params
from reconstruction.surfaces.config import SurfaceConfig
from reconstruction.surfaces.fused import FusedCloud
from reconstruction.surfaces.rbf import RbfParams, rbf_surface

RADIUS_M = 0.05
# The cap z >= 0.5 R of the sphere (a third of its height; area pi R^2 = 79 cm^2): what one side
# of a scan sees, with a rim where the data stop.
CAP_Z_M = 0.5 * RADIUS_M
NOISE_M = 0.0002  # stereo noise of the fused cloud, 1 sigma
CONFIG = SurfaceConfig(methods=("rbf",))


def _params(config: SurfaceConfig = CONFIG) -> RbfParams:
    return rbf_params(config)


def _cap_cloud(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """About one point per mm^2 (the fused cloud's 1 mm voxels), area-uniform on the cap (z
    uniform, Archimedes), radial noise, true outward normals."""
    rng = np.random.default_rng(seed)
    n = 8000
    z = rng.uniform(CAP_Z_M, RADIUS_M, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    rho = np.sqrt(RADIUS_M**2 - z**2)
    normals = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1) / RADIUS_M
    points = normals * (RADIUS_M + rng.normal(0, NOISE_M, n))[:, None]
    return points, normals


@pytest.fixture(scope="module")
def cap():
    points, normals = _cap_cloud()
    return points, normals, rbf_surface(points, normals, _params())


def test_rbf_lies_on_the_sphere(cap):
    _, _, surface = cap
    assert len(surface.triangles) > 1000
    err_m = np.abs(np.linalg.norm(surface.vertices, axis=1) - RADIUS_M)
    # 0.2 mm noise averaged over the ~4 points per 2 mm centre and the smoothing.
    assert np.median(err_m) < 0.0003
    assert np.quantile(err_m, 0.99) < 0.001


def test_rbf_covers_the_cap_and_no_more(cap):
    points, _, surface = cap
    v, t = surface.vertices, surface.triangles
    # Nothing below the rim beyond the cut distance (an RBF alone would close the sphere or
    # flare out), nor anywhere farther than that from the data.
    assert v[:, 2].min() > CAP_Z_M - CONFIG.rbf_max_distance_m - 0.0005
    d, _ = cKDTree(points).query(v)
    assert d.max() <= CONFIG.rbf_max_distance_m
    # The whole cap is meshed: area between the cap's and that of the cap grown by the cut.
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    cap_area = 2 * np.pi * RADIUS_M * (RADIUS_M - CAP_Z_M)
    grown = 2 * np.pi * RADIUS_M * (RADIUS_M - CAP_Z_M + CONFIG.rbf_max_distance_m)
    assert 0.97 * cap_area < area.sum() < grown


def test_rbf_triangles_face_out(cap):
    _, _, surface = cap
    v, t = surface.vertices, surface.triangles
    normal = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    outward = np.einsum("ij,ij->i", normal, v[t].mean(axis=1))
    assert (outward > 0).mean() > 0.99


def test_rbf_is_deterministic(cap):
    points, normals, first = cap
    second = rbf_surface(points.copy(), normals.copy(), _params())
    assert np.array_equal(first.vertices, second.vertices)
    assert np.array_equal(first.triangles, second.triangles)


def test_rbf_method_through_build_surface():
    """The registered method: a SurfaceMesh named rbf, cleaned, coloured from the cloud."""
    points, normals = _cap_cloud(seed=1)
    colors = np.tile(np.array([[200, 100, 50]], np.uint8), (len(points), 1))
    mesh = build_surface("rbf", FusedCloud(points, colors, normals), CONFIG)
    assert mesh.name == "rbf"
    err_m = np.abs(np.linalg.norm(mesh.vertices, axis=1) - RADIUS_M)
    assert np.median(err_m) < 0.0003
    assert mesh.colors is not None and (mesh.colors == [200, 100, 50]).all()


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("rbf_kernel", "gaussian"),
        ("rbf_neighbors", 0),
        ("rbf_neighbors", 2.5),
        ("rbf_smoothing", -1.0),
        ("rbf_voxel_size_m", 0.0),
        ("rbf_offset_m", float("nan")),
        ("rbf_max_centres", 10),
        ("rbf_centre_spacing_m", -0.002),
        ("rbf_max_distance_m", "2 mm"),
    ],
)
def test_bad_rbf_setting_is_refused_naming_the_field(field, value):
    with pytest.raises(ScannerError) as error:
        SurfaceConfig(methods=("rbf",), **{field: value})
    message = str(error.value)
    assert f"surfaces.{field}" in message and "\n" not in message


def test_rbf_grid_too_fine_is_refused_before_allocating():
    points, normals = _cap_cloud()
    config = SurfaceConfig(methods=("rbf",), rbf_voxel_size_m=1e-5)
    with pytest.raises(ScannerError, match="surfaces.rbf_voxel_size_m"):
        rbf_surface(points, normals, _params(config))


def test_rbf_is_a_known_method():
    assert SurfaceConfig(methods=("poisson", "tsdf", "rbf")).methods[-1] == "rbf"
