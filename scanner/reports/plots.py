"""The pictures of a reconstruction (PNG, rendered headless): per-view residuals, every surface
coloured by its deviation from the truth on a fixed scale, and the hangings."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display on CI or robot PCs
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reconstruction.common.transforms import invert, pose_difference, transform_points  # noqa: E402
from reconstruction.evaluation.deviation import deviation_stats, signed_distances  # noqa: E402
from reconstruction.evaluation.metrics import TriangleSurface  # noqa: E402
from reconstruction.hangings.merge import to_first_frame  # noqa: E402
from reconstruction.pipeline import ReconstructionResult  # noqa: E402


def per_view_residuals(result: ReconstructionResult) -> list[dict]:
    """Per view, where the reconstruction placed it against where the robot says it is (mm,
    deg): `nominal_*` with the nominal X_FC (the mount error shows in every view alike),
    `estimated_*` with the estimated X_FC (what is left per view: the robot's own per-pose
    errors and ICP noise). The placed pose is the final one, taken back into the view's own
    hanging's frame (where the robot's poses are). Empty without registration."""
    to_estimate = invert(result.X_FC_nominal) @ result.X_FC
    T_of = to_first_frame(result.alignments)  # the final poses are in the first's frame
    rows = []
    for v in result.views:
        if v.X_WC_registered is None:
            return []
        X_WC_placed = invert(T_of[v.hanging]) @ v.X_WC
        nominal_t, nominal_r = pose_difference(v.X_WC_kinematic, X_WC_placed)
        left_t, left_r = pose_difference(v.X_WC_kinematic @ to_estimate, X_WC_placed)
        rows.append(
            {
                "index": v.index,
                "nominal_mm": 1e3 * nominal_t,
                "nominal_deg": math.degrees(nominal_r),
                "estimated_mm": 1e3 * left_t,
                "estimated_deg": math.degrees(left_r),
            }
        )
    return rows


def _residual_plot(result: ReconstructionResult, path: Path) -> None:
    fig, axes = plt.subplots(3, 1, figsize=(9, 8))
    edges = [e for e in result.edges if e.inlier_rmse_m is not None]
    labels = [f"{e.source}-{e.target}" for e in edges]
    colours = ["tab:green" if e.status == "kept" else "tab:red" for e in edges]
    axes[0].bar(range(len(edges)), [1e3 * e.inlier_rmse_m for e in edges], color=colours)
    axes[0].set_ylabel("ICP inlier RMSE (mm)")
    axes[0].set_title("Pairwise ICP edges (green kept, red pruned)")
    axes[0].set_xticks(range(len(edges)), labels, rotation=90, fontsize=6)
    rows = per_view_residuals(result)
    x = np.arange(len(rows))
    for ax, unit in zip(axes[1:], ("mm", "deg")):
        ax.bar(
            x - 0.2,
            [r[f"nominal_{unit}"] for r in rows],
            0.4,
            color="0.6",
            label="robot pose at the nominal X_FC",
        )
        ax.bar(
            x + 0.2,
            [r[f"estimated_{unit}"] for r in rows],
            0.4,
            color="tab:blue",
            label="robot pose at the estimated X_FC",
        )
        ax.set_xticks(x, [str(r["index"]) for r in rows], fontsize=7)
        ax.set_ylabel(f"difference ({unit})")
    # One legend for both panels, above them on the right: matplotlib's search for the "best"
    # place among the bars took over a second under load, and any place inside can hide a bar.
    axes[1].legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False)
    axes[1].set_title("Per view: registered camera pose against the robot's", loc="left")
    axes[2].set_xlabel("view")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


PASS_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
HANGINGS_MAX_POINTS = 60_000  # more dots than the 550 x 550 px panels can show; drawing is slow


def _hangings_map(result: ReconstructionResult, path: Path) -> None:
    """The merged cloud in two orthographic views, each hanging's points in its own colour."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 5))
    placed = sorted({v.hanging for v in result.views})  # a hanging left out has no points
    per_pass = HANGINGS_MAX_POINTS // max(1, len(placed))
    rng = np.random.default_rng(0)
    for h in placed:
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


def surface_deviations(
    result: ReconstructionResult,
    truth: TriangleSurface,
    out: Path,
    scale_m: float,
    tolerance_m: float,
) -> tuple[dict[str, str], dict[str, dict]]:
    """Per surface: deviation_<name>.png (its vertices' signed distance to the truth on the
    fixed scale +-scale_m) and the statistics (report units)."""
    from scanner.reports.deviation_picture import write_deviation_picture

    paths, stats = {}, {}
    for name, mesh in result.meshes.items():
        if not len(mesh.triangles):
            continue
        signed = signed_distances(mesh.vertices, truth)
        s = deviation_stats(signed, tolerance_m)
        paths[f"deviation_{name}"] = f"deviation_{name}.png"
        title = f"{name} mesh against the true surface ({s.points} vertices)"
        write_deviation_picture(
            mesh.vertices,
            mesh.triangles,
            signed,
            s,
            scale_m,
            out / paths[f"deviation_{name}"],
            title,
        )
        stats[name] = s.as_report()
    return paths, stats


def write_plots(
    result: ReconstructionResult,
    out: Path,
    truth: TriangleSurface | None = None,
    scale_m: float = 0.001,
    tolerance_m: float = 0.0005,
) -> tuple[dict[str, str], dict[str, dict]]:
    """The pictures (name -> file in `out`) and, with the truth, every surface's deviation
    statistics."""
    paths = {"residuals": "residuals.png"}
    _residual_plot(result, out / paths["residuals"])
    if result.alignments:
        paths["hangings"] = "hangings.png"
        _hangings_map(result, out / paths["hangings"])
    stats: dict[str, dict] = {}
    if truth is not None:
        more, stats = surface_deviations(result, truth, out, scale_m, tolerance_m)
        paths.update(more)
    return paths, stats
