"""The plain peer of the real-data benchmark: OpenCV's SGBM on calibrated pairs of DTU MVS views,
merged into one cloud, scored without a reference surface.

What it does, and nothing more (a peer the product must beat, not a second product):
- Reads DTU's folder as IDR / NeuS preprocess it: cameras_sphere.npz (world_mat_i = K [R | t],
  world in millimetres; scale_mat_i maps the unit sphere onto the working sphere), images/
  (distortion already removed) and mask/. Lengths become metres on reading.
- Pairs: each reference view with its nearest view whose camera centre lies 6-20 deg away as seen
  from the working sphere's centre (DTU's neighbours are about 10 deg apart).
- Rectification: cv2.stereoRectify from the calibrated poses (the relative pose of the two X_WC,
  no distortion; alpha -1: the original focal length), with the rectified principal points moved
  so that the working sphere's centre images at the rectified images' centres (stereoRectify
  centres them on the cameras' axes, and the views' 10-16 deg of relative rotation then put up to
  a third of the object outside; Q is rebuilt for the moved points). A vertical pair rectifies to
  vertical
  epipolar lines; SGBM searches along rows, so both rectified images are transposed (the row
  becomes the column; a transpose is a 90 deg rotation and a mirror, which changes nothing for
  SGBM's costs) and, where the second camera lies on the reference's left (or above it), mirrored
  so that the reference is SGBM's left image. The disparity map is turned back the same way.
- Disparity range: from the working sphere (centre, radius from scale_mat) in the rectified
  reference camera: d = f B / Z over the sphere's depth span.
- SGBM as OpenCV's documentation and stereo_match.py sample set it: grey images, block 5,
  P1 = 8 x 5^2, P2 = 32 x 5^2, uniqueness 10, speckle window 100 range 2, disp12MaxDiff 1.
- Points: reprojected with Q into the rectified reference camera, turned into the reference
  camera (R1^T) and then into W; only pixels inside the reference view's mask (the mask
  rectified with the image) and within the working sphere are kept.
- Merged: all pairs' points, voxel-downsampled (0.2 mm) and cleaned by Open3D's statistical
  outlier removal (20 neighbours, 2 sigma). No surface: this is the peer's cloud.
- Measures: silhouette agreement of the merged cloud with every view's mask
  (`cloud_silhouette_agreement`: exact splats of half the point pitch, closed 3 px), and split-half
  agreement of the clouds of even-reference and odd-reference pairs (`split_half_agreement`,
  common radius 1 mm x downscale: about four pixel footprints at the 0.65 m standoff).

Options: --data DIR (DTU scan folder), --downscale N (images and masks shrunk N times), --views
(comma-separated indices; all by default), --out DIR (writes peer_cloud.ply, peer_even.ply,
peer_odd.ply). Prints one JSON line; progress on stderr. `seconds`: the peer's own time (pairs,
merge); `measure_seconds`: the measures, the halves' own merges included.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from reconstruction.common.transforms import invert, make_pose, transform_points
from reconstruction.evaluation.silhouette import cloud_silhouette_agreement
from reconstruction.evaluation.split_half import split_half_agreement

MM_TO_M = 1e-3
MIN_PAIR_ANGLE_RAD = math.radians(6.0)
MAX_PAIR_ANGLE_RAD = math.radians(20.0)
VOXEL_M = 0.2e-3
OUTLIER_NEIGHBOURS = 20
OUTLIER_STD_RATIO = 2.0
BLOCK_PX = 5
COMMON_RADIUS_M = 1.0e-3  # at full resolution; times the downscale
CLOSE_RADIUS_PX = 3


@dataclass(frozen=True, eq=False)
class View:
    """One DTU view, downscaled: K (3, 3) pixels, X_WC (4, 4) metres, grey image, mask."""

    index: int
    K: np.ndarray
    X_WC: np.ndarray
    grey: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True, eq=False)
class Sphere:
    """The working sphere (metres): where the object lies."""

    centre_W: np.ndarray
    radius_m: float


def _decompose(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K and X_WC (world units) of a 3x4 projection P = K [R_CW | t]."""
    K, R_CW, c_h = cv2.decomposeProjectionMatrix(P)[:3]
    K = K / K[2, 2]
    K[0, 1] = 0.0  # DTU's skew is ~1e-5 px; stereoRectify assumes none
    return K, make_pose(R_CW.T, (c_h[:3] / c_h[3]).ravel())


def _shrunk_K(K: np.ndarray, downscale: int) -> np.ndarray:
    """K of the image shrunk `downscale` times by area: pixel centres at integer coordinates,
    so a centre u becomes (u + 0.5) / n - 0.5."""
    K = K.copy()
    K[:2, :2] /= downscale
    K[:2, 2] = (K[:2, 2] + 0.5) / downscale - 0.5
    return K


def load_dtu(data: Path, downscale: int, indices: list[int] | None) -> tuple[list[View], Sphere]:
    cameras = np.load(data / "cameras_sphere.npz")
    n_views = len([k for k in cameras.files if k.startswith("world_mat_") and "inv" not in k])
    indices = list(range(n_views)) if indices is None else indices
    scale_mat = cameras["scale_mat_0"]
    sphere = Sphere(scale_mat[:3, 3] * MM_TO_M, float(scale_mat[0, 0]) * MM_TO_M)
    views = []
    for i in indices:
        K, X_WC_mm = _decompose(cameras[f"world_mat_{i}"][:3, :4])
        X_WC = X_WC_mm.copy()
        X_WC[:3, 3] *= MM_TO_M
        grey = cv2.imread(str(data / "images" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        mask = cv2.imread(str(data / "mask" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE)
        if grey is None or mask is None:
            sys.exit(f"opencv_sgbm_peer: view {i}: image or mask missing in {data}")
        if downscale > 1:
            size = (grey.shape[1] // downscale, grey.shape[0] // downscale)
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
            mask = cv2.resize(mask, size, interpolation=cv2.INTER_AREA)
            K = _shrunk_K(K, downscale)
        views.append(View(i, K, X_WC, grey, mask > 127))
    return views, sphere


def _angle_rad(a_W: np.ndarray, b_W: np.ndarray) -> float:
    cos = a_W @ b_W / (np.linalg.norm(a_W) * np.linalg.norm(b_W))
    return math.acos(float(np.clip(cos, -1.0, 1.0)))


def pairs_of(views: list[View], sphere: Sphere) -> list[tuple[int, int]]:
    """(reference, partner) positions in `views`: each view's nearest view 6-20 deg away."""
    rays_W = [v.X_WC[:3, 3] - sphere.centre_W for v in views]
    pairs = []
    for i, ray_W in enumerate(rays_W):
        angles = [(_angle_rad(ray_W, other_W), j) for j, other_W in enumerate(rays_W) if j != i]
        allowed = [(a, j) for a, j in angles if MIN_PAIR_ANGLE_RAD <= a <= MAX_PAIR_ANGLE_RAD]
        if allowed:
            pairs.append((i, min(allowed)[1]))
    return pairs


def _to_rows(image: np.ndarray, vertical: bool, mirrored: bool) -> np.ndarray:
    out = image.T if vertical else image
    return np.ascontiguousarray(out[:, ::-1] if mirrored else out)


def _from_rows(image: np.ndarray, vertical: bool, mirrored: bool) -> np.ndarray:
    out = image[:, ::-1] if mirrored else image
    return np.ascontiguousarray(out.T if vertical else out)


def _centred(P1, P2, p_rect1, size, axis):
    """P1, P2 with principal points moved so that the point p_rect1 (rectified reference frame)
    images at both rectified images' centres: stereoRectify centres the rectified images on the
    cameras' axes, and with DTU's 10-16 deg between the views (roll included) up to a third of
    the object then fell outside them (alpha -1); alpha 1 keeps it all, but only by shrinking the
    focal length by up to a third. Across the baseline both share the shift (rows stay epipolar
    lines); along it each camera gets its own, which Q's last term accounts for."""
    P1, P2 = P1.copy(), P2.copy()
    centre_px = (np.asarray(size, float) - 1.0) / 2.0
    h = np.append(p_rect1, 1.0)
    a1 = (P1 @ h)[:2] / (P1 @ h)[2]
    a2 = (P2 @ h)[:2] / (P2 @ h)[2]
    across = 1 - axis
    P1[across, 2] += centre_px[across] - a1[across]
    P2[across, 2] += centre_px[across] - a1[across]
    P1[axis, 2] += centre_px[axis] - a1[axis]
    # P2's translation column holds f T; moving its principal point moves that term's partner.
    P2[axis, 2] += centre_px[axis] - a2[axis]
    return P1, P2


def _q(P1: np.ndarray, P2: np.ndarray, axis: int) -> np.ndarray:
    """stereoRectify's Q (disparity-to-depth) for P1, P2 with the baseline along `axis`."""
    f = P1[0, 0]
    T = P2[axis, 3] / f
    return np.array(
        [
            [1.0, 0.0, 0.0, -P1[0, 2]],
            [0.0, 1.0, 0.0, -P1[1, 2]],
            [0.0, 0.0, 0.0, f],
            [0.0, 0.0, -1.0 / T, (P1[axis, 2] - P2[axis, 2]) / T],
        ]
    )


def pair_points_W(ref: View, other: View, sphere: Sphere) -> np.ndarray:
    """Points (N, 3) in W, metres, that SGBM finds inside the reference view's mask."""
    size = (ref.grey.shape[1], ref.grey.shape[0])
    X_C2C1 = invert(other.X_WC) @ ref.X_WC
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        ref.K, None, other.K, None, size, X_C2C1[:3, :3], X_C2C1[:3, 3],
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1,
    )  # fmt: skip
    # P2's translation column is f T in the rectified frame along x (horizontal pair) or y.
    vertical = abs(P2[1, 3]) > abs(P2[0, 3])
    axis = 1 if vertical else 0
    centre_rect = R1 @ transform_points(invert(ref.X_WC), sphere.centre_W[None])[0]
    P1, P2 = _centred(P1, P2, centre_rect, size, axis)
    Q = _q(P1, P2, axis)
    # The rectified coordinate along the baseline of the reference minus the other's is
    # (c1 - c2) - f T / Z; SGBM wants it positive-going (other camera on the reference's right,
    # or below it): mirror both images otherwise, which negates it.
    sign = -1.0 if P2[axis, 3] > 0 else 1.0
    fB_px_m = abs(P2[axis, 3])
    offset_px = sign * (P1[axis, 2] - P2[axis, 2])
    maps1 = cv2.initUndistortRectifyMap(ref.K, None, R1, P1, size, cv2.CV_32FC1)
    maps2 = cv2.initUndistortRectifyMap(other.K, None, R2, P2, size, cv2.CV_32FC1)
    rect1 = cv2.remap(ref.grey, *maps1, cv2.INTER_LINEAR)
    rect2 = cv2.remap(other.grey, *maps2, cv2.INTER_LINEAR)
    mask1 = cv2.remap(ref.mask.astype(np.uint8), *maps1, cv2.INTER_NEAREST) > 0

    z_near_m = max(centre_rect[2] - sphere.radius_m, 0.2 * centre_rect[2])
    z_far_m = centre_rect[2] + sphere.radius_m
    d_min = int(math.floor(fB_px_m / z_far_m + offset_px))
    n_disp = 16 * math.ceil((fB_px_m / z_near_m + offset_px - d_min + 1) / 16)
    sgbm = cv2.StereoSGBM_create(
        minDisparity=d_min,
        numDisparities=n_disp,
        blockSize=BLOCK_PX,
        P1=8 * BLOCK_PX**2,
        P2=32 * BLOCK_PX**2,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
    )
    mirrored = sign < 0
    left = _to_rows(rect1, vertical, mirrored)
    right = _to_rows(rect2, vertical, mirrored)
    disparity = sgbm.compute(left, right).astype(np.float32) / 16.0  # SGBM: 4 fraction bits
    disparity = _from_rows(disparity, vertical, mirrored)
    valid = mask1 & (disparity >= d_min)
    # Q takes the signed difference reference - other along the baseline's axis (y's for a
    # vertical pair, as stereoRectify's own Q does).
    p_rect = cv2.reprojectImageTo3D(sign * disparity, Q)[valid].astype(float)
    # R1 turns the reference camera into the rectified one: p_rect = R1 p_C1. einsum, not `@`:
    # BLAS on (N, 3) x (3, 3) products ran 40x slower on the loaded 2-core machine.
    R_WR = ref.X_WC[:3, :3] @ R1.T
    p_W = np.einsum("ij,nj->ni", R_WR, p_rect) + ref.X_WC[:3, 3]
    inside = np.linalg.norm(p_W - sphere.centre_W, axis=1) <= sphere.radius_m
    return p_W[inside]


def merged(clouds: list[np.ndarray]) -> np.ndarray:
    """The clouds' union, voxel-downsampled and cleaned of statistical outliers."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(clouds)))
    cloud = cloud.voxel_down_sample(VOXEL_M)
    cloud, _ = cloud.remove_statistical_outlier(OUTLIER_NEIGHBOURS, OUTLIER_STD_RATIO)
    return np.asarray(cloud.points)


def _write(path: Path, points_W: np.ndarray) -> None:
    o3d.io.write_point_cloud(
        str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_W))
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="DTU scan folder")
    parser.add_argument("--downscale", type=int, default=1)
    parser.add_argument("--views", default=None, help="comma-separated view indices (all)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    indices = None if args.views is None else [int(v) for v in args.views.split(",")]

    start = time.perf_counter()
    views, sphere = load_dtu(args.data, args.downscale, indices)
    pairs = pairs_of(views, sphere)
    per_pair = []
    for n, (i, j) in enumerate(pairs):
        per_pair.append(pair_points_W(views[i], views[j], sphere))
        print(
            f"pair {n + 1}/{len(pairs)}: {views[i].index}-{views[j].index} "
            f"{len(per_pair[-1])} points",
            file=sys.stderr,
        )
    cloud = merged(per_pair)
    seconds = time.perf_counter() - start

    measures_start = time.perf_counter()
    even = merged([p for (i, _), p in zip(pairs, per_pair) if views[i].index % 2 == 0])
    odd = merged([p for (i, _), p in zip(pairs, per_pair) if views[i].index % 2 == 1])
    silhouette = cloud_silhouette_agreement(
        cloud,
        [(v.K, v.X_WC, v.grey.shape[1], v.grey.shape[0], v.mask) for v in views],
        close_radius_px=CLOSE_RADIUS_PX,
    )
    halves = split_half_agreement(even, odd, COMMON_RADIUS_M * args.downscale)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        _write(args.out / "peer_cloud.ply", cloud)
        _write(args.out / "peer_even.ply", even)
        _write(args.out / "peer_odd.ply", odd)
    report = {
        "downscale": args.downscale,
        "views": len(views),
        "pairs": len(pairs),
        "seconds": round(seconds, 1),
        "measure_seconds": round(time.perf_counter() - measures_start, 1),
        "points": len(cloud),
        "silhouette": silhouette.summary(),
        "split_half": {
            "median_mm": round(halves.median_m * 1e3, 4),
            "p90_mm": round(halves.p90_m * 1e3, 4),
            "normal_median_mm": round(halves.normal_median_m * 1e3, 4),
            "normal_p90_mm": round(halves.normal_p90_m * 1e3, 4),
            "common_share": round(halves.common_share, 4),
            "common_radius_mm": COMMON_RADIUS_M * args.downscale * 1e3,
            "points_even": len(even),
            "points_odd": len(odd),
        },
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
