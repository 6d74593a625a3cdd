"""plan.png: top and side views of the cell with a scan plan's viewpoints, drawn headless.

Matplotlib's Agg canvas on a Figure of its own (not pyplot), so no display and no global
backend is touched. Metres on both axes, equal scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

from robots.models.workcell import WorkcellConfig
from scanner.plan_only.records import ScanPlan

REACHABLE_COLOUR = "tab:green"
UNREACHABLE_COLOUR = "tab:red"
ARROW_M = 0.12  # length of the drawn viewing direction
# (axis of the picture's x, axis of its y, title) for the two views.
PROJECTIONS = ((0, 1, "top view (x, y)"), (0, 2, "side view (x, z)"))


def draw_plan(plan: ScanPlan, cell: WorkcellConfig, path: Path) -> None:
    """Write the picture of `plan` in `cell` to `path` (PNG, 1400 x 700 px)."""
    plan_figure(plan, cell).savefig(path, format="png")


def plan_figure(plan: ScanPlan, cell: WorkcellConfig) -> Figure:
    """The picture of `plan` in `cell`: every viewpoint of the first hanging numbered."""
    figure = Figure(figsize=(14, 7), dpi=100)
    FigureCanvasAgg(figure)
    # The viewpoints are the same in every hanging; the first hanging's tour is drawn.
    shown = [v for v in plan.viewpoints if v.hanging == 0 and v.X_WC is not None]
    for k, (i, j, title) in enumerate(PROJECTIONS):
        axes = figure.add_subplot(1, 2, k + 1)
        _cell(axes, cell, plan, i, j)
        _viewpoints(axes, shown, i, j)
        axes.set_title(title)
        axes.set_xlabel("xyz"[i] + " (m)")
        axes.set_ylabel("xyz"[j] + " (m)")
        axes.set_aspect("equal")
        axes.autoscale_view()
    hangings = (
        f"; the same viewpoints in each of {plan.hangings} hangings" if plan.hangings > 1 else ""
    )
    figure.suptitle(
        f"scan plan: {plan.reachable_count} of {len(plan.viewpoints)} views reachable (green; "
        f"red unreachable), numbered in tour order, then those dropped before the tour; "
        f"estimated robot time {plan.robot_time_s:.1f} s{hangings}"
    )
    return figure


def _cell(axes, cell: WorkcellConfig, plan: ScanPlan, i: int, j: int) -> None:
    """Boxes, the robot base at the world origin, the rod and the object's bounding sphere."""
    for box in cell.boxes:
        corner = (box.p_WB[i] - box.size[i] / 2, box.p_WB[j] - box.size[j] / 2)
        axes.add_patch(
            Rectangle(corner, box.size[i], box.size[j], color=box.rgba[:3], alpha=0.35, lw=0)
        )
        axes.annotate(box.name, corner, (2, 2), textcoords="offset points", fontsize=8)
    axes.plot([0.0], [0.0], marker="^", markersize=12, color="black", linestyle="none")
    axes.annotate("robot base", (0.0, 0.0), (4, -12), textcoords="offset points", fontsize=8)
    c = np.asarray(cell.object_center_m, float)
    if j == 2:
        axes.plot([c[i], c[i]], [c[2], cell.rod_top_z_m], color="grey", lw=1)
    centre = plan.scan_center_m
    axes.add_patch(
        Circle((centre[i], centre[j]), plan.keep_out_radius_m, fill=False, ls="--", color="blue")
    )
    axes.annotate(
        "object bounding sphere",
        (centre[i], centre[j] + plan.keep_out_radius_m),
        (0, 3),
        textcoords="offset points",
        ha="center",
        fontsize=8,
        color="blue",
    )


def _viewpoints(axes, shown, i: int, j: int) -> None:
    """Camera positions with their optical axes (+z of C), the tour as a thin line."""
    visited = sorted((v for v in shown if v.reachable), key=lambda v: v.order)
    if visited:
        path = np.array([v.X_WC[:3, 3] for v in visited])
        axes.plot(path[:, i], path[:, j], color=REACHABLE_COLOUR, lw=0.6, alpha=0.6)
    for v in shown:
        colour = REACHABLE_COLOUR if v.reachable else UNREACHABLE_COLOUR
        p_WC, z_W = v.X_WC[:3, 3], v.X_WC[:3, 2]
        axes.plot([p_WC[i]], [p_WC[j]], marker="o", markersize=4, color=colour)
        axes.annotate(
            "",
            (p_WC[i] + ARROW_M * z_W[i], p_WC[j] + ARROW_M * z_W[j]),
            (p_WC[i], p_WC[j]),
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 0.8},
        )
        axes.annotate(
            str(v.number),
            (p_WC[i], p_WC[j]),
            (3, 3),
            textcoords="offset points",
            fontsize=7,
            color="black" if v.reachable else colour,
        )
