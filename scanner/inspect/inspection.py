"""`scanner inspect MODEL --reference CAD`: how far a measured part is from its reference.

The reference is aligned onto the model (reported), then every model vertex's signed deviation
from it gives the statistics, the coloured picture and a pass/fail line, beside the surface
metrics the reconstruction report uses (so inspecting a simulated scan against its true mesh
gives the report's figures). Results go to a new folder; nothing is replaced without --force.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from reconstruction.common.errors import RefusedResultError, ScannerError
from scanner.scan_dir.outputs import INSPECTION_MARKER

if TYPE_CHECKING:  # the parser reads InspectOptions' defaults without loading Open3D
    from reconstruction.evaluation.metrics import TriangleSurface

# The least share of the model that must lie on the aligned reference for the comparison to
# mean anything (below it the parts differ, or the unit or the alignment is wrong).
MIN_OVERLAP = 0.5
REFERENCE_TRIANGLES = 8_000  # the reference's wireframe on model.html


@dataclass(frozen=True)
class InspectOptions:
    reference: Path
    tolerance_m: float = 0.0005
    scale_m: float = 0.001
    min_within: float = 0.95
    reference_unit: str = "auto"
    # "best-fit": the reference is aligned onto the model; "none": it is taken where it is.
    align: str = "best-fit"
    out: Path | None = None
    force: bool = False
    # How the lengths were typed on the command line ({"tolerance": "0.5"}), for messages.
    typed: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 0.0 < self.min_within <= 1.0:
            raise ScannerError(f"--min-within: expected a share in (0, 1], got {self.min_within}")


@dataclass(frozen=True, eq=False)
class ModelSource:
    """The mesh to inspect, the camera (or stereo eye) centres that saw it (from a
    reconstruction; None for a bare mesh file), and where the inspection folder goes by
    default."""

    mesh_path: Path
    camera_centres: list[np.ndarray] | None
    default_root: Path


@dataclass(frozen=True, eq=False)
class InspectRun:
    report: dict
    out: Path

    @property
    def passed(self) -> bool:
        return bool(self.report["passed"])


def read_mesh(path: Path, what: str) -> TriangleSurface:
    from reconstruction.common.mesh_files import read_triangle_mesh
    from reconstruction.evaluation.metrics import TriangleSurface

    path = Path(path)
    if not path.is_file():
        raise ScannerError(f"{what} {path}: no such file")
    mesh = read_triangle_mesh(path)
    if not len(mesh.triangles):
        raise ScannerError(f"{what} {path}: no triangles read (expected a .ply/.obj/.stl mesh)")
    return TriangleSurface(np.asarray(mesh.vertices, float), np.asarray(mesh.triangles))


def model_source(target: Path) -> ModelSource:
    """A mesh file as it is; a scan directory's `results/` or a results folder: its headline
    mesh (world frame, metres) and its views' camera centres."""
    from reconstruction.common.yaml_files import read_yaml

    target = Path(target)
    if target.is_file():
        return ModelSource(target, None, target.parent)
    results = target / "results" if (target / "scan.yaml").is_file() else target
    report_path = results / "report.json"
    if not (results / "reconstruction.yaml").is_file() or not report_path.is_file():
        raise ScannerError(
            f"{target}: not a mesh file, a scan directory with a reconstruction, or a results "
            "folder (expected reconstruction.yaml and report.json)"
        )
    primary = json.loads(report_path.read_text()).get("primary_surface", "poisson")
    details = read_yaml(results / "reconstruction.yaml", "reconstruction")
    # A stereo view saw what both of its cameras saw, as in the scan's own report (results
    # written before the eyes were recorded: the left camera's centre).
    centres = [
        np.array(v.get("eye_centres_W_m", np.array(v["X_WC"])[:3, 3]), float)
        for v in details.get("views", [])
    ]
    return ModelSource(results / f"mesh_{primary}.ply", centres or None, results)


def inspect_model(
    model: TriangleSurface,
    reference: TriangleSurface,
    options: InspectOptions,
    camera_centres: list[np.ndarray] | None = None,
    metric_samples: int = 200_000,
):
    """The reference aligned onto the model, the deviations and the report (no files)."""
    from reconstruction.common.transforms import transform_points
    from reconstruction.evaluation.deviation import deviation_stats, signed_distances
    from reconstruction.evaluation.metrics import TriangleSurface, evaluate_surface
    from reconstruction.evaluation.reference_alignment import (
        align_reference,
        fit_as_given,
        reference_unit,
        scaled,
    )

    unit = options.reference_unit
    if unit == "auto":
        unit = reference_unit(model.vertices, reference.vertices)
    fit = align_reference if options.align == "best-fit" else fit_as_given
    alignment = fit(model.vertices, reference, unit=unit)
    if alignment.overlap < MIN_OVERLAP:
        raise RefusedResultError(
            f"--reference: could not align it onto the model: only {alignment.overlap:.0%} of "
            f"the model lies within {1e3 * alignment.inlier_distance_m:g} mm of it at the best "
            f"fit (at least {MIN_OVERLAP:.0%} needed); check it is the same part and its unit "
            f"(read as {unit}; --reference-unit) and, with --align none, its placement",
        )
    in_metres = scaled(reference, unit)
    placed = TriangleSurface(
        transform_points(alignment.X_MR, in_metres.vertices), in_metres.triangles
    )
    signed = signed_distances(model.vertices, placed)
    stats = deviation_stats(signed, options.tolerance_m)
    metrics = evaluate_surface(
        None, placed, result_mesh=model, camera_centres_W=camera_centres, n_samples=metric_samples
    )
    report = {
        "reference_unit": unit,
        "alignment": {
            "start": alignment.start,
            "X_MR": alignment.X_MR.tolist(),
            "overlap": alignment.overlap,
            "inlier_rms_mm": 1e3 * alignment.inlier_rms_m,
            "inlier_distance_mm": 1e3 * alignment.inlier_distance_m,
        },
        "deviation": stats.as_report(),
        "metrics": metrics,
        "min_within": options.min_within,
        "passed": stats.within_tolerance >= options.min_within,
    }
    return placed, signed, stats, report


def require_lengths_fit(options: InspectOptions, model: TriangleSurface) -> None:
    """A tolerance or colour scale as large as the model itself is a unit typed wrongly (0.5
    for 0.5 mm reads 500 mm and passes anything): refused, with both readings."""
    from reconstruction.common.lengths import require_below

    size_m = float(np.ptp(model.vertices, axis=0).max())
    for name, length_m in (("tolerance", options.tolerance_m), ("scale", options.scale_m)):
        text = options.typed.get(name, f"{length_m:g}")
        require_below(f"--{name}", text, length_m, size_m, "not less than the model's size")


def run_inspect(target: Path, options: InspectOptions) -> InspectRun:
    from reconstruction.surfaces.meshes import MESH_SUFFIXES
    from scanner.scan_dir.results_folder import (
        free_results_dir,
        require_replaceable,
        staged_folder,
    )

    if Path(options.reference).suffix.lower() not in MESH_SUFFIXES:
        raise ScannerError(
            f"--reference {options.reference}: expected a mesh file ({', '.join(MESH_SUFFIXES)})"
        )
    source = model_source(target)
    model = read_mesh(source.mesh_path, "model")
    require_lengths_fit(options, model)
    reference = read_mesh(options.reference, "--reference")
    if options.out is not None:
        require_replaceable(options.out, INSPECTION_MARKER, options.force, "inspection")
    out = options.out or free_results_dir(source.default_root, INSPECTION_MARKER, "inspection")
    placed, signed, stats, report = inspect_model(model, reference, options, source.camera_centres)
    report = {"model": str(source.mesh_path), "reference": str(options.reference), **report}
    with staged_folder(out, INSPECTION_MARKER) as staging:
        _write_files(staging, model, placed, signed, stats, report, options)
    return InspectRun(report, out)


def _write_files(folder: Path, model, placed, signed, stats, report, options) -> None:
    import open3d as o3d

    from scanner.reports.deviation_picture import deviation_colours, write_deviation_picture
    from scanner.scan_dir.captures import atomic_write_text

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(model.vertices), o3d.utility.Vector3iVector(model.triangles)
    )
    mesh.vertex_colors = o3d.utility.Vector3dVector(deviation_colours(signed, options.scale_m))
    o3d.io.write_triangle_mesh(str(folder / "deviation_mesh.ply"), mesh)
    ref = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(placed.vertices), o3d.utility.Vector3iVector(placed.triangles)
    )
    o3d.io.write_triangle_mesh(str(folder / "reference_aligned.ply"), ref)
    title = f"model against {Path(report['reference']).name} ({stats.points} vertices)"
    write_deviation_picture(
        model.vertices,
        model.triangles,
        signed,
        stats,
        options.scale_m,
        folder / "deviation.png",
        title,
    )
    report["scale_mm"] = 1e3 * options.scale_m
    report["files"] = ["deviation.png", "deviation_mesh.ply", "reference_aligned.ply"]
    if _write_page(folder, model, placed, options.scale_m):
        report["files"].append("model.html")
    (folder / "summary.md").write_text(inspection_summary(report))
    # Written last: its presence marks a finished inspection.
    atomic_write_text(folder / INSPECTION_MARKER, json.dumps(report, indent=2) + "\n")


def _write_page(folder: Path, model, placed, scale_m: float) -> bool:
    """model.html: the model coloured by its deviation (the picture's scale) over the aligned
    reference as a wireframe. A page that fails to write is a warning: the inspection stands
    without it."""
    import logging

    from reconstruction.evaluation.deviation import signed_distances
    from scanner.reports.model_page import PAGE_NAME, write_model_page
    from scanner.reports.model_page_layers import DisplayMesh, ModelScene, decimated

    try:
        v, t = decimated(model.vertices, model.triangles)
        # A wireframe of every triangle would hide the model behind it.
        rv, rt = decimated(placed.vertices, placed.triangles, REFERENCE_TRIANGLES)
        scene = ModelScene(
            mesh=DisplayMesh(v, t, signed_distances(v, placed)),
            scale_m=scale_m,
            colour_meaning="model: signed deviation from the aligned reference (grey wireframe)",
            reference=DisplayMesh(rv, rt, np.zeros(len(rv))),
        )
        write_model_page(scene, folder / PAGE_NAME, "scanner inspection")
    except Exception as e:  # noqa: BLE001 - the inspection's figures stand without the page
        logging.getLogger("scanner.inspect").warning(
            "%s not written (%s: %s)", PAGE_NAME, type(e).__name__, e
        )
        return False
    return True


def verdict_line(report: dict) -> str:
    d = report["deviation"]
    word = "PASS" if report["passed"] else "FAIL"
    return (
        f"{word}: {100 * d['within_tolerance']:.1f} % of the model within +-"
        f"{d['tolerance_mm']:g} mm of the reference (required {100 * report['min_within']:g} %)"
    )


def inspection_summary(report: dict) -> str:
    from scanner.reports.judgement import TABLE_HEAD, TRUTH_FIGURES, figure_row

    a, d = report["alignment"], report["deviation"]
    lines = [
        "# Inspection against a reference",
        "",
        f"**{verdict_line(report)}**",
        "",
        f"- model: `{report['model']}`; reference: `{report['reference']}` (read in "
        f"{report['reference_unit']})",
        f"- alignment (start: {a['start']}): {100 * a['overlap']:.1f} % of the model within "
        f"{a['inlier_distance_mm']:g} mm of the reference, inlier RMS {a['inlier_rms_mm']:.3f} mm",
        f"- signed deviation (positive outside the reference): mean {d['mean_mm']:.3f} mm, "
        f"RMS {d['rms_mm']:.3f} mm, p90 |d| {d['p90_abs_mm']:.3f} mm, max |d| "
        f"{d['max_abs_mm']:.3f} mm over {d['points']} vertices",
        "",
        *TABLE_HEAD,
        figure_row("rms_mm", d["rms_mm"]),
        figure_row("p90_abs_mm", d["p90_abs_mm"]),
        *(figure_row(k, report["metrics"][k]) for k in TRUTH_FIGURES if k in report["metrics"]),
        "",
        f"Colour scale fixed at +-{report['scale_mm']:g} mm (blue inside, red outside): "
        "`deviation_mesh.ply` carries the same colours for CloudCompare or MeshLab.",
        "",
        "![deviation](deviation.png)",
    ]
    if "model.html" in report.get("files", []):
        lines += [
            "",
            "The model over the reference in 3D, in any browser: [`model.html`](model.html), "
            "or `scanner view` on this folder.",
        ]
    return "\n".join(lines) + "\n"
