"""`scanner calibrate --offline DIR` for a folder without robot poses: the cameras alone.

A new stereo camera is calibrated before any hand-eye work (one folder of board images for one
camera, or `left/` and `right/` with the same file names for a pair): cv2.calibrateCamera per
camera, cv2.stereoCalibrate, rectification, and a report that says whether it is good enough
for stereo matching (RMS, per-image errors, rectified epipolar error, baseline, focal lengths,
board coverage). The calibration file holds the cameras and the camera tool's nominal X_FC,
marked as not calibrated: `scan` and `reconstruct` correct the mount from the scan itself.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reconstruction.calibration.board_reasons import larger_chessboard
from reconstruction.calibration.boards import BoardSpec
from reconstruction.calibration.camera_quality import board_coverage, epipolar_error
from reconstruction.calibration.file import Calibration, save_calibration
from reconstruction.calibration.intrinsics import calibrate_camera, calibrate_stereo
from reconstruction.calibration.observations import PoseObservation
from reconstruction.calibration.settings import CalibrationSettings
from reconstruction.common.errors import ScannerError
from robots.models.camera_tool import nominal_X_FC
from scanner.calibrate.solve import no_board_anywhere
from scanner.scan_dir.captures import atomic_write_text
from scanner.scan_dir.outputs import CALIBRATION_FILE
from scanner.scan_dir.results_folder import require_replaceable, staged_folder


@dataclass(frozen=True, eq=False)
class CamerasRun:
    results_dir: Path
    calibration_file: Path
    report: dict


def _pair_key(name: str) -> str:
    """A file name with its side removed: left01.jpg and right01.jpg pair, as do 01.png and
    01.png (OpenCV's stereo sample names them so)."""
    return re.sub(r"(?i)left|right", "", name, count=1)


def _paired_images(root: Path, images: list[Path]) -> list[tuple[Path, Path | None]]:
    """(left, right) paths; each image of left/ needs one in right/ with the same name (apart
    from the words left/right)."""
    if not ((root / "left").is_dir() and (root / "right").is_dir()):
        return [(p, None) for p in images]
    suffixes = {p.suffix.lower() for p in images}
    right = {
        _pair_key(p.name): p for p in (root / "right").iterdir() if p.suffix.lower() in suffixes
    }
    left = {_pair_key(p.name): p for p in images}
    only_left = sorted(left[k].name for k in set(left) - set(right))
    only_right = sorted(right[k].name for k in set(right) - set(left))
    if only_left or only_right:
        detail = "; ".join(
            f"{what}: {', '.join(names[:5])}{' ...' if len(names) > 5 else ''}"
            for what, names in (
                ("no partner in right/", only_left),
                ("no partner in left/", only_right),
            )
            if names
        )
        raise ScannerError(
            f"{root}: left/ has {len(left)} images and right/ {len(right)}; each left image "
            f"needs a right one of the same name, apart from the word left/right ({detail})"
        )
    return [(p, right[_pair_key(p.name)]) for p in images]


def _observations(
    root: Path, images: list[Path], board: BoardSpec, settings: CalibrationSettings, read, detect
) -> tuple[list[PoseObservation], tuple[int, int]]:
    observations, size, larger = [], None, []
    for left_path, right_path in _paired_images(root, images):
        right = None
        for path in (left_path, right_path):
            if path is None:
                continue
            image = read(path)
            this_size = (image.shape[1], image.shape[0])
            if size is not None and this_size != size:
                raise ScannerError(
                    f"{path}: image size {this_size[0]}x{this_size[1]} differs from the first "
                    f"image's {size[0]}x{size[1]}; all images must come from one camera setting"
                )
            size = this_size
            if path is right_path:
                right, _ = detect(board, image, settings)
            else:
                left, why = detect(board, image, settings)
                if left is not None:
                    larger.append(larger_chessboard(board, image))
        observations.append(PoseObservation(left_path.stem, None, left, right, why))
    if not any(o.left is not None for o in observations):
        raise ScannerError(f"{root}: {no_board_anywhere(board, observations)}")
    require_board_size(root, board, larger)
    return observations, size


def require_board_size(root: Path, board: BoardSpec, larger: list) -> None:
    """ScannerError when most images with a board also show a larger grid
    (`larger_chessboard` of each)."""
    seen = [grid for grid in larger if grid is not None]
    if len(seen) > len(larger) / 2:
        raise ScannerError(
            f"{root}: the board has more squares than given: {len(seen)} of {len(larger)} images "
            f"show a grid of {seen[0][0]}x{seen[0][1]} inner corners, {board.cols}x{board.rows} "
            f"squares have {board.cols - 1}x{board.rows - 1}; check --board-size (squares, "
            "not inner corners)"
        )


def _per_image(names, rms, found) -> list[dict]:
    by_name = dict(zip(names, np.atleast_2d(rms).tolist()))
    out = []
    for o in found:
        record = {"name": o.name}
        if o.name in by_name:
            values = by_name[o.name]
            record["rms_px"] = values if len(values) > 1 else values[0]
        else:
            record["rms_px"] = None
        out.append(record)
    return out


def calibrate_cameras(
    root: Path,
    images: list[Path],
    board: BoardSpec,
    settings: CalibrationSettings,
    out_dir: Path,
    force: bool,
    read,
    detect,
) -> CamerasRun:
    """The cameras of `root` from its board images; results in out_dir/results."""
    results_dir = Path(out_dir) / "results"
    require_replaceable(results_dir, CALIBRATION_FILE, force, "calibration")
    observations, size = _observations(root, images, board, settings, read, detect)
    found = [o for o in observations if o.left is not None]
    not_found = {o.name: o.not_found for o in observations if o.left is None}
    report: dict = {
        "source": f"offline:{root}",
        "mode": "cameras only (no robot poses: hand-eye not calibrated)",
        "images": len(observations),
        "boards_found": len(found),
        "board_not_found_reasons": not_found,
        "image_size": list(size),
        "board_coverage": board_coverage([o.left for o in found], size),
    }
    stereo = None
    if any(o.right is not None for o in observations):
        cal = calibrate_stereo(board, observations, size, settings)
        stereo = cal.stereo
        epi = epipolar_error(stereo, observations)
        report.update(
            {
                "boards_found_right": sum(o.right is not None for o in observations),
                "stereo_rms_px": cal.rms_px,
                "left_rms_px": cal.left.rms_px,
                "right_rms_px": cal.right.rms_px,
                "epipolar_median_px": epi.median_px,
                "epipolar_p95_px": epi.p95_px,
                "epipolar_max_px": epi.max_px,
                "baseline_m": stereo.baseline_m,
                "focal_px": [float(stereo.left.K[0, 0]), float(stereo.right.K[0, 0])],
                "per_image": _per_image(cal.view_names, cal.view_rms_px, found),
            }
        )
        camera = stereo.left
        X_FC = nominal_X_FC(stereo.baseline_m)
    else:
        cal = calibrate_camera(board, [o.left for o in found], size, settings)
        camera = cal.camera
        report.update(
            {
                "camera_rms_px": cal.rms_px,
                "focal_px": [float(camera.K[0, 0])],
                "per_image": _per_image([o.name for o in found], cal.view_rms_px, found),
            }
        )
        X_FC = nominal_X_FC()
    calibration = Calibration(
        X_FC,
        stereo,
        camera,
        report["source"],
        quality={"hand_eye": "not calibrated: the camera tool's nominal X_FC", **report},
    )
    with staged_folder(results_dir, CALIBRATION_FILE) as staging:
        atomic_write_text(staging / "report.json", json.dumps(report, indent=2) + "\n")
        atomic_write_text(staging / "report.txt", report_text(report))
        save_calibration(calibration, staging / CALIBRATION_FILE)
    return CamerasRun(results_dir, results_dir / CALIBRATION_FILE, report)


def report_text(report: dict) -> str:
    lines = [
        f"camera calibration from {report['source']} ({report['mode']})",
        f"board found in {report['boards_found']} of {report['images']} images"
        + (
            f" (right camera: {report['boards_found_right']})"
            if "boards_found_right" in report
            else ""
        ),
    ]
    for name, why in report["board_not_found_reasons"].items():
        lines.append(f"  {name}: {why}")
    if "stereo_rms_px" in report:
        lines += [
            f"stereo RMS reprojection: {report['stereo_rms_px']:.3f} px (left alone "
            f"{report['left_rms_px']:.3f}, right alone {report['right_rms_px']:.3f})",
            f"rectified epipolar error: median {report['epipolar_median_px']:.3f} px, p95 "
            f"{report['epipolar_p95_px']:.3f} px (stereo matching wants well under 1 px)",
            f"baseline: {1e3 * report['baseline_m']:.2f} mm; focal lengths: "
            + ", ".join(f"{f:.1f}" for f in report["focal_px"])
            + " px",
        ]
    else:
        lines += [
            f"RMS reprojection: {report['camera_rms_px']:.3f} px; focal length "
            f"{report['focal_px'][0]:.1f} px"
        ]
    lines.append(
        f"board coverage of the image: {100 * report['board_coverage']:.0f} % (the distortion "
        "model is extrapolated where no board was seen)"
    )
    lines.append("per image RMS (px):")
    for r in report["per_image"]:
        rms = r["rms_px"]
        text = "-" if rms is None else " / ".join(f"{v:.3f}" for v in np.atleast_1d(rms))
        lines.append(f"  {r['name']}: {text}")
    return "\n".join(lines) + "\n"
