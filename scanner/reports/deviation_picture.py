"""The deviation picture: a mesh coloured by its signed deviation from a reference, on a fixed,
stated scale (so two runs compare by eye), beside the histogram of the deviations."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display on CI or robot PCs
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reconstruction.evaluation.deviation import DeviationStats  # noqa: E402
from scanner.reports.mesh_render import render_mesh  # noqa: E402

COLOUR_MAP = "RdBu_r"  # blue inside the reference, white on it, red outside
MAP_STEPS = 256


def colour_map_rgb() -> np.ndarray:
    """The colour map as (MAP_STEPS, 3) uint8 RGB, from -scale to +scale."""
    rgba = matplotlib.colormaps[COLOUR_MAP](np.linspace(0.0, 1.0, MAP_STEPS))
    return np.round(255 * rgba[:, :3]).astype(np.uint8)


def scale_position(signed_m: np.ndarray, scale_m: float) -> np.ndarray:
    """Each deviation's place on the colour map, [0, 1]; beyond +-scale_m it saturates."""
    return np.clip(0.5 + 0.5 * np.asarray(signed_m, float) / scale_m, 0.0, 1.0)


def deviation_colours(signed_m: np.ndarray, scale_m: float) -> np.ndarray:
    """Per value its RGB colour in [0, 1] (e.g. vertex colours of a PLY for CloudCompare)."""
    rgb = colour_map_rgb()
    index = np.round(scale_position(signed_m, scale_m) * (MAP_STEPS - 1)).astype(int)
    return rgb[index] / 255.0


def write_deviation_picture(
    vertices: np.ndarray,
    triangles: np.ndarray,
    signed_m: np.ndarray,
    stats: DeviationStats,
    scale_m: float,
    path: Path,
    title: str,
) -> Path:
    """Two rendered views of the mesh coloured by `signed_m` (one per vertex) on -scale..+scale,
    the colour bar, and the histogram of all deviations with the tolerance band."""
    images = render_mesh(
        vertices, triangles, values01=scale_position(signed_m, scale_m), colour_map=colour_map_rgb()
    )
    mm = 1e3 * np.asarray(signed_m, float)
    scale_mm, tol_mm = 1e3 * scale_m, 1e3 * stats.tolerance_m
    fig = plt.figure(figsize=(13, 5.2))
    grid = fig.add_gridspec(2, 3, width_ratios=(1, 1, 1.1), height_ratios=(1, 0.05))
    views = []
    for k, image in enumerate(images[:2]):
        ax = fig.add_subplot(grid[0, k])
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title(("from below", "from the side")[k])
        views.append(ax)
    norm = matplotlib.colors.Normalize(-scale_mm, scale_mm)
    mappable = matplotlib.cm.ScalarMappable(norm=norm, cmap=COLOUR_MAP)
    fig.colorbar(
        mappable,
        cax=fig.add_subplot(grid[1, :2]),
        orientation="horizontal",
        label="signed deviation (mm): blue inside the reference, red outside",
    )
    ax = fig.add_subplot(grid[:, 2])
    bins = np.linspace(-scale_mm, scale_mm, 61)
    ax.hist(np.clip(mm, -scale_mm, scale_mm), bins=bins, color="0.45")
    ax.axvspan(-tol_mm, tol_mm, color="tab:green", alpha=0.15, label=f"tolerance +-{tol_mm:g} mm")
    ax.set_xlim(-scale_mm, scale_mm)
    ax.set_xlabel(f"signed deviation (mm), clipped to the scale +-{scale_mm:g} mm")
    ax.set_ylabel("vertices")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(
        f"RMS {1e3 * stats.rms_m:.3f} mm, p90 |d| {1e3 * stats.p90_abs_m:.3f} mm, "
        f"{100 * stats.within_tolerance:.1f} % within",
        fontsize=9,
    )
    fig.suptitle(title)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
