"""Benchmark: stereo from two poses of one camera on real images (DTU MVS scan 24).

DTU's camera rode an industrial arm to 49 positions about 0.12 m apart at 0.65 m from a model
house. The views given (`--views`) are paired (`two_view.pairing`, each view with its nearest
usable neighbour) and each pair goes through `two_view.cloud.pair_cloud` at `--downscale`,
restricted to the house's mask. Per pair: points, seconds, epipolar error (median, px at the
matching scale), whether the pose was refined. Split-half: the clouds of the pairs with an
even reference and those with an odd one, in W, and the distance from each point of the first
to the nearest point of the second (median, p90; in mm): what two independent measurements of
one surface disagree by.
Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np
from benchmark_data import REAL, require
from scipy.spatial import cKDTree

from reconstruction.common.transforms import make_pose, transform_points
from reconstruction.stereo.camera_model import PinholeCamera
from reconstruction.stereo.params import stereo_params
from reconstruction.two_view.cloud import TwoViewConfig, pair_cloud
from reconstruction.two_view.epipolar import EpipolarConfig
from reconstruction.two_view.pairing import PairingConfig, pair_views

# Split-half points farther than this from the other half count as surface only one half saw.
OVERLAP_M = 0.005


def load_dtu(root, views):
    """[(image RGB, mask, camera, X_WC in metres)], working centre (m), radius (m).

    cameras_sphere.npz: world_mat_i = K [R | t] in millimetres; scale_mat_i maps the unit
    sphere around the object into the world."""
    data = np.load(root / "cameras_sphere.npz")
    scale = data["scale_mat_0"]
    loaded = []
    for i in views:
        K, R_CW, c_h = cv2.decomposeProjectionMatrix(data[f"world_mat_{i}"][:3])[:3]
        K = K / K[2, 2]
        K[0, 1] = 0.0  # numerically zero skew
        X_WC = make_pose(R_CW.T, (c_h[:3] / c_h[3]).ravel() / 1000.0)
        image = cv2.cvtColor(cv2.imread(str(root / f"images/{i:06d}.png")), cv2.COLOR_BGR2RGB)
        mask = cv2.imread(str(root / f"mask/{i:03d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        camera = PinholeCamera(K, np.zeros(5), image.shape[1], image.shape[0])
        loaded.append((image, mask, camera, X_WC))
    return loaded, scale[:3, 3] / 1000.0, scale[0, 0] / 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", default="0,1,2,3,4,5,6,7,8,9", help="DTU view numbers")
    parser.add_argument("--downscale", type=float, default=2.0)
    parser.add_argument("--pairs-per-view", type=int, default=1)
    parser.add_argument(
        "--max-epipolar-px",
        type=float,
        default=EpipolarConfig().max_error_px,
        help="refine a pair's relative pose above this median epipolar error",
    )
    parser.add_argument(
        "--stereo", default="{}", help='StereoParams fields as JSON, e.g. {"block_size_px": 5}'
    )
    args = parser.parse_args()
    root = require(REAL / "dtu_mvs_scan24", "bench_two_view")
    numbers = [int(v) for v in args.views.split(",")]
    views, centre_m, radius_m = load_dtu(root, numbers)
    pairs = pair_views(
        [v[3] for v in views], centre_m, PairingConfig(pairs_per_view=args.pairs_per_view)
    )
    config = TwoViewConfig(
        downscale=args.downscale, epipolar=EpipolarConfig(max_error_px=args.max_epipolar_px)
    )
    params = stereo_params(**json.loads(args.stereo))
    per_pair, halves = [], {0: [], 1: []}
    for pair in pairs:
        image_i, mask_i, cam_i, X_WCi = views[pair.reference]
        image_j, _, cam_j, X_WCj = views[pair.other]
        start = time.perf_counter()
        cloud = pair_cloud(
            image_i,
            image_j,
            cam_i,
            cam_j,
            X_WCi,
            X_WCj,
            centre_m,
            radius_m,
            params,
            mask_i,
            config,
        )
        seconds = time.perf_counter() - start
        reference = numbers[pair.reference]
        halves[reference % 2].append(transform_points(X_WCi, cloud.points_C))
        per_pair.append(
            {
                "pair": [reference, numbers[pair.other]],
                "baseline_mm": round(pair.baseline_m * 1e3, 1),
                "angle_deg": round(float(np.degrees(pair.angle_rad)), 2),
                "quarter_turns": cloud.quarter_turns,
                "points": len(cloud),
                "mask_fraction": round(len(cloud) / (mask_i.sum() / args.downscale**2), 3),
                "seconds": round(seconds, 2),
                "epipolar_median_px": round(cloud.pose.before.median_px, 3),
                "epipolar_median_after_px": round(cloud.pose.after.median_px, 3),
                "epipolar_p90_px": round(cloud.pose.before.p90_px, 3),
                "matches": cloud.pose.before.matches,
                "refined": cloud.refined,
            }
        )
        print(json.dumps(per_pair[-1]), flush=True)
    result = {
        "downscale": args.downscale,
        "max_epipolar_px": args.max_epipolar_px,
        "stereo": json.loads(args.stereo),
        "pairs": per_pair,
    }
    if halves[0] and halves[1]:
        even, odd = np.concatenate(halves[0]), np.concatenate(halves[1])
        distances_m, _ = cKDTree(odd).query(even, workers=-1)
        result["split_half"] = {
            "even_points": len(even),
            "odd_points": len(odd),
            "median_mm": round(float(np.median(distances_m)) * 1e3, 3),
            "p90_mm": round(float(np.percentile(distances_m, 90)) * 1e3, 3),
            # Where the halves overlap: points with a partner within OVERLAP_M (the rest saw
            # surface the other half did not).
            "overlap_fraction": round(float(np.mean(distances_m < OVERLAP_M)), 3),
            "overlap_median_mm": round(
                float(np.median(distances_m[distances_m < OVERLAP_M])) * 1e3, 3
            ),
        }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
