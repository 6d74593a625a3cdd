"""`scanner reconstruct`'s work for one scan directory, given the command's options: shared by
the single run and the batch (one Ray task per scan)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.reconstruct.stages import ReconstructRun


@dataclass(frozen=True)
class ReconstructOptions:
    """The flags of `scanner reconstruct`, applied to every scan given."""

    config: Path | None = None
    calibration: Path | None = None
    no_icp: bool = False
    no_handeye: bool = False
    formats: str | None = None
    out: Path | None = None
    force: bool = False
    progress: bool = False
    units: str | None = None  # --units, --frame, --decimate: processing.mesh_export
    frame: str | None = None
    decimate: int | None = None
    # Imported recordings only: whose masks restrict the clouds (all, even, none), and the
    # working volume (x, y, z, radius in metres) or box (x, y, z min, then max, metres).
    masks: str | None = None
    volume: tuple[float, float, float, float] | None = None
    box: tuple[float, float, float, float, float, float] | None = None


def reconstruct_one(scan_dir: Path, options: ReconstructOptions) -> ReconstructRun:
    """The scan's own settings unless --config; results in a free SCAN_DIR/results[-N] unless
    --out (which must not hold a reconstruction, unless --force)."""
    from reconstruction.calibration.file import load_calibration
    from robots.sensors import sensor_named
    from scanner.reconstruct.stages import (
        RECONSTRUCTION_MARKER,
        free_reconstruction_dir,
        load_processing_config,
        run_reconstruct,
    )
    from scanner.scan_dir.manifest import open_scan, require_robot_scan
    from scanner.scan_dir.results_folder import require_replaceable

    scan = open_scan(scan_dir)
    # An imported recording (one camera, its pose per view) has its own reconstruction
    # (scanner.recordings), which the command chooses.
    require_robot_scan(scan, "this reconstruction")
    given = {"--masks": options.masks, "--volume": options.volume, "--box": options.box}
    flag = next((f for f, v in given.items() if v is not None), None)
    if flag is not None:
        raise ScannerError(f"{flag}: only for an imported recording; {scan_dir} is a scan")
    if options.config is not None:
        processing = load_processing_config(options.config)
    else:
        processing = scan.config.processing
    rec = processing.reconstruction
    if options.no_icp:
        rec = replace(rec, icp=replace(rec.icp, enabled=False))
    if options.no_handeye:
        rec = replace(rec, handeye=replace(rec.handeye, enabled=False))
    formats = processing.mesh_formats
    if options.formats:
        formats = tuple("." + f.strip().lstrip(".").lower() for f in options.formats.split(","))
    processing = replace(
        processing,
        reconstruction=rec,
        mesh_formats=formats,
        mesh_export=_mesh_export(processing.mesh_export, options),
    )
    stereo = X_FC = None
    if options.calibration is not None:
        calibration = load_calibration(options.calibration)
        X_FC = calibration.X_FC
        # The scan's sensor reads the calibration (None: the scan's own camera model).
        stereo = sensor_named(scan.sensor).offline_model(
            scan.camera_model, calibration, str(options.calibration)
        )
        if calibration.robot is not None:
            # X_FC was estimated with the arm's own errors: the poses must carry them too.
            from robots.arms.default import arm_of
            from robots.models.kinematics import corrected_kinematics

            flange_pose = corrected_kinematics(
                arm_of(scan.config.robot), calibration.robot, f"--calibration {options.calibration}"
            )
            scan = replace(scan, flange_pose=flange_pose)
    out = options.out or free_reconstruction_dir(scan_dir)
    if options.out is not None:
        require_replaceable(options.out, RECONSTRUCTION_MARKER, options.force, "reconstruction")
    origin = {}
    if options.config is not None:
        origin["processing_from"] = f"--config {options.config}"
    if options.calibration is not None:
        origin["X_FC_given"] = f"from --calibration {options.calibration}"
    return run_reconstruct(
        scan, processing, out, X_FC, stereo, progress=options.progress, origin=origin
    )


def _mesh_export(export, options: ReconstructOptions):
    """processing.mesh_export with --units, --frame and --decimate applied (an error names the
    flag)."""
    from scanner.configs.flags import for_flag

    for flag, key, value in (
        ("--units", "units", options.units),
        ("--frame", "frame", options.frame),
        ("--decimate", "decimate_triangles", options.decimate),
    ):
        if value is not None:
            export = for_flag(flag, lambda: replace(export, **{key: value}))  # noqa: B023
    return export


def summary_lines(report: dict) -> list[str]:
    """What the command prints about one finished reconstruction: the run, then (with truth)
    the headline figures with their verdicts."""
    r = report
    lines = [
        f"reconstruct: {r['captures_used']} captures used, {len(r['captures_skipped'])} "
        f"skipped, {r['reconstruct_s']:.1f} s"
    ]
    line = metrics_line(r)
    if line:
        lines.append(line)
    s, h = r.get("silhouette"), r.get("split_half")
    if s:  # a recording: no truth, its own measures
        where = "held-out views" if s["held_out"] else "views whose masks it used"
        m = s["mesh"]
        lines.append(
            f"silhouettes on {len(s['views'])} {where}: IoU {m['iou_median']:.3f} median, "
            f"{m['iou_worst']:.3f} worst; mask covered {m['coverage_median']:.3f} median"
        )
    if h:
        lines.append(
            f"split-half agreement: {h['median_mm']:.3f} mm median, {h['p90_mm']:.3f} mm p90 on "
            f"{100 * h['common_share']:.1f} % of the points"
        )
    return lines


def metrics_line(report: dict) -> str | None:
    """The headline figures against the truth, each with its verdict (None without truth)."""
    from scanner.reports.judgement import FIGURES

    r = report
    if "chamfer_mm" not in r:
        return None

    def judged(key: str, text: str) -> str:
        return f"{text} ({FIGURES[key].verdict(r[key])})"

    parts = []
    if "chamfer_observed_mm" in r:
        parts.append(
            judged("chamfer_observed_mm", f"Chamfer {r['chamfer_observed_mm']:.3f} mm observed")
        )
        parts.append(judged("observed_fraction", f"{r['observed_fraction']:.0%} of it seen"))
    parts.append(f"whole object {r['chamfer_mm']:.3f} mm, F-score(1 mm) {r['fscore_1mm']:.3f}")
    if "handeye_error_mm" in r:
        parts.append(
            judged(
                "handeye_error_mm",
                f"hand-eye error {r['handeye_error_mm']:.3f} mm / {r['handeye_error_deg']:.4f} deg",
            )
        )
    return f"{r['primary_surface']}: " + "; ".join(parts)
