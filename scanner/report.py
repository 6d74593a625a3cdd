"""Human-readable results: plots (PNG, rendered headless) and results/summary.md.

Units follow scanner.units: accuracy figures in mm and degrees, everything else SI.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display on CI or robot PCs
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reconstruction.metrics import (  # noqa: E402
    SURFACE_METRIC_KEYS,
    TriangleSurface,
    distances_to_mesh,
)
from reconstruction.pipeline import ReconstructionResult  # noqa: E402
from reconstruction.transforms import pose_difference, transform_points  # noqa: E402


def _residual_plot(result: ReconstructionResult, path: Path) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(8, 6))
    edges = [e for e in result.edges if e.inlier_rmse_m is not None]
    labels = [f"{e.source}-{e.target}" for e in edges]
    colours = ["tab:green" if e.status == "kept" else "tab:red" for e in edges]
    axes[0].bar(range(len(edges)), [1e3 * e.inlier_rmse_m for e in edges], color=colours)
    axes[0].set_ylabel("ICP inlier RMSE (mm)")
    axes[0].set_title("Pairwise ICP edges (green kept, red pruned)")
    axes[0].set_xticks(range(len(edges)), labels, rotation=90, fontsize=6)
    moves = [pose_difference(v.X_WC_kinematic, v.X_WC) for v in result.views]
    idx = [v.index for v in result.views]
    axes[1].bar(np.arange(len(idx)) - 0.2, [1e3 * t for t, _ in moves], 0.4, label="mm")
    axes[1].bar(
        np.arange(len(idx)) + 0.2, [math.degrees(r) * 10 for _, r in moves], 0.4, label="deg x 10"
    )
    axes[1].set_xticks(range(len(idx)), [str(i) for i in idx], fontsize=7)
    axes[1].set_xlabel("view")
    axes[1].set_title("Final camera pose vs the robot's kinematic pose (nominal X_FC)")
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


ERROR_MAP_MAX_POINTS = 60_000  # more dots than the 550 x 550 px panels can show; drawing is slow


def _error_map(vertices: np.ndarray, error_mm: np.ndarray, path: Path, title: str) -> None:
    """Two orthographic views of the mesh vertices coloured by their distance to the truth."""
    if len(vertices) > ERROR_MAP_MAX_POINTS:
        pick = np.random.default_rng(0).choice(len(vertices), ERROR_MAP_MAX_POINTS, replace=False)
        vertices, error_mm = vertices[pick], error_mm[pick]
    fig, axes = plt.subplots(1, 2, figsize=(10, 5))
    order = np.argsort(vertices[:, 1])
    for ax, (a, b, name) in zip(axes, ((0, 2, "x-z (side)"), (0, 1, "x-y (from below)"))):
        keep = order if b == 2 else np.argsort(-vertices[:, 2])
        sc = ax.scatter(
            vertices[keep, a],
            vertices[keep, b],
            c=error_mm[keep],
            s=0.3,
            cmap="turbo",
            vmin=0,
            vmax=max(2.0, float(np.percentile(error_mm, 95))),
        )
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("m")
    fig.colorbar(sc, ax=axes, label="distance to the true surface (mm)")
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


PASS_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _hangings_map(result: ReconstructionResult, path: Path) -> None:
    """The merged cloud in two orthographic views, each hanging's points in its own colour."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 5))
    per_pass = ERROR_MAP_MAX_POINTS // max(1, len(result.alignments) + 1)
    rng = np.random.default_rng(0)
    for h in range(len(result.alignments) + 1):
        points = [
            transform_points(v.X_WC, c.points_C)
            for v, c in zip(result.views, result.clouds)
            if v.hanging == h
        ]
        p = np.vstack(points)
        p = p[rng.choice(len(p), min(per_pass, len(p)), replace=False)]
        for ax, (a, b) in zip(axes, ((0, 2), (0, 1))):
            colour = PASS_COLOURS[h % len(PASS_COLOURS)]
            ax.scatter(p[:, a], p[:, b], s=0.2, color=colour, label=f"hanging {h + 1}")
    for ax, name in zip(axes, ("x-z (side)", "x-y (from below)")):
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("m")
    axes[0].legend(markerscale=20)
    fig.suptitle("Merged model, coloured by hanging (first hanging's frame)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_plots(
    result: ReconstructionResult,
    out: Path,
    truth: TriangleSurface | None = None,
    primary: str = "poisson",
) -> dict:
    paths = {"residuals": "residuals.png"}
    _residual_plot(result, out / paths["residuals"])
    if result.alignments:
        paths["hangings"] = "hangings.png"
        _hangings_map(result, out / paths["hangings"])
    mesh = result.meshes.get(primary)
    if truth is not None and mesh is not None and len(mesh.vertices):
        error_mm = 1e3 * distances_to_mesh(mesh.vertices, truth)
        paths["error_map"] = "error_map.png"
        _error_map(
            mesh.vertices,
            error_mm,
            out / paths["error_map"],
            f"{primary} mesh: median {np.median(error_mm):.2f} mm, "
            f"p90 {np.percentile(error_mm, 90):.2f} mm",
        )
    return paths


def _fmt(value, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _hangings_lines(report: dict) -> list[str]:
    passes = report.get("hangings")
    if not passes or len(passes) < 2:
        return []
    lines = [
        "",
        "## Hangings (each further one aligned onto those before it)",
        "",
        "| hanging | views | overlap | inlier RMS mm | seen-through | verified | error mm, deg |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in passes:
        error = (
            f"{_fmt(p['alignment_error_mm'])} / {_fmt(p['alignment_error_deg'])}"
            if "alignment_error_mm" in p
            else "-"
        )
        lines.append(
            f"| {p['hanging']} | {p['views']} | {_fmt(p.get('overlap', '-'))} | "
            f"{_fmt(p.get('inlier_rms_mm', '-'))} | {_fmt(p.get('free_space_violation', '-'))} | "
            f"{p.get('verified', 'reference')} | {error} |"
        )
    return lines


def handeye_warning(report: dict) -> str | None:
    """The warning for a hand-eye correction that did not converge (None when it did or did
    not run)."""
    if report.get("handeye_converged", True):
        return None
    failures = "; ".join(report.get("handeye_diagnosis", {}).get("failures", []))
    return (
        f"WARNING: the hand-eye correction did not converge ({failures}); the model may be "
        "distorted. Calibrate the camera mount (`scanner calibrate`) and reconstruct with "
        "--calibration; the cloud at the nominal hand-eye transform is kept as "
        "fused_cloud_nominal.ply."
    )


def write_summary(report: dict, out: Path) -> Path:
    lines = ["# Scan result", ""]
    warning = handeye_warning(report)
    if warning:
        lines += [f"**{warning}**", ""]
    if "views_planned" in report:
        lines += [
            f"- views captured: {report.get('views_captured')} of {report['views_planned']}"
            f" ({report.get('views_skipped', 0)} skipped)",
            f"- robot motion: {_fmt(report.get('robot_motion_s', 0.0), 1)} s,"
            f" wall time: {_fmt(report.get('wall_s', 0.0), 1)} s",
        ]
    if "chamfer_mm" in report:
        lines += [
            "",
            f"## Metrics of the {report.get('primary_surface')} mesh against the truth",
            "",
            "| metric | value |",
            "|---|---|",
        ]
        lines += [f"| {k} | {_fmt(report[k])} |" for k in SURFACE_METRIC_KEYS if k in report]
        if "observed_fraction" in report:
            lines += [
                "",
                "`observed_fraction` is the share of the true surface that some camera had in "
                "view (unoccluded, within 80 deg of facing it); the `*_observed_*` metrics are "
                "restricted to it, the others count the unseen part (e.g. the top of a hung "
                "object) as missing.",
            ]
    if "coverage_estimate" in report:
        lines += [
            "",
            f"Coverage estimate (no truth): {_fmt(report['coverage_estimate'])} of the closed "
            f"surface was in some camera's view; about {_fmt(1e4 * report['unseen_area_m2'], 1)}"
            " cm^2 were not (a further hanging would show them).",
        ]
    closed = report.get("closed_model")
    if closed:
        lines += [
            "",
            f"Closed model (`mesh_poisson_closed`, for collision models and prints): "
            f"{'watertight' if closed['watertight'] else 'NOT watertight'}; "
            f"{_fmt(1e4 * closed['filled_area_m2'], 1)} cm^2 of it bridge where no data are "
            "(filled, not seen).",
        ]
    lines += _hangings_lines(report)
    if "handeye_error_mm" in report:
        lines += [
            "",
            "## Hand-eye transform X_FC (error against the simulator's truth)",
            "",
            f"- nominal: {_fmt(report['handeye_error_before_mm'])} mm, "
            f"{_fmt(report['handeye_error_before_deg'])} deg",
            f"- estimated: {_fmt(report['handeye_error_mm'])} mm, "
            f"{_fmt(report['handeye_error_deg'])} deg",
        ]
    if "X_FC_change_mm" in report:
        lines += [
            f"- correction applied: {_fmt(report['X_FC_change_mm'])} mm, "
            f"{_fmt(report['X_FC_change_deg'])} deg"
        ]
    if "handeye_diagnosis" in report:
        d = report["handeye_diagnosis"]
        verdict = "converged" if report["handeye_converged"] else "NOT converged"
        lines += [
            f"- the correction {verdict} (judged without truth): "
            f"{_fmt(100 * d['match_fraction'], 0)} % of the points meet the overlapping views "
            f"(RMS {_fmt(d['match_rms_mm'])} mm), AX = XB on the ICP motions agrees within "
            f"{_fmt(d['axxb_disagreement_mm'])} mm / {_fmt(d['axxb_disagreement_deg'])} deg, "
            f"the last round moved it {_fmt(d['last_change_mm'])} mm"
        ]
    if "outputs" in report:
        lines += ["", "## Files", ""] + [f"- `{p}`" for p in report["outputs"].values()]
    for name, path in report.get("plots", {}).items():
        lines += ["", f"![{name}]({path})"]
    path = out / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path
