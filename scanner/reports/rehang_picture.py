"""rehang_N.png: the instruction for the next hanging as a picture for the operator: the model so
far as it hangs now (two side views and one from above), the part still unseen in red, the
side to bring to the top (arrow) and where to clamp (star)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display on CI or robot PCs
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reconstruction.evaluation.coverage import SeenSurface  # noqa: E402

MAX_POINTS = 12_000


def write_rehang_picture(
    seen: SeenSurface,
    up_W: np.ndarray,
    clamp_W: np.ndarray,
    centre_W,
    hanging: int,
    path: Path,
    heading: str | None = None,
    toward_W: np.ndarray | None = None,
) -> None:
    """The picture for pass `hanging` (0-based) in the cell frame of the object as it hangs
    (`heading`: another instruction for the arrow and the star, as a table's "lay it on";
    `toward_W`: a second, orange arrow, the side to turn towards the robot)."""
    p, c = seen.samples.points, np.asarray(centre_W, float)
    rng = np.random.default_rng(0)
    pick = rng.choice(len(p), min(MAX_POINTS, len(p)), replace=False)
    p, unseen = p[pick], ~seen.seen[pick]
    radius = float(np.max(np.linalg.norm(p - c, axis=1)))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6))
    views = (
        ("x", "z", 0, 2, "side, from the robot's right"),
        ("y", "z", 1, 2, "side, from the robot"),
        ("x", "y", 0, 1, "from above"),
    )
    for ax, (xl, yl, i, j, title) in zip(axes, views):
        ax.scatter(p[~unseen, i], p[~unseen, j], s=0.3, color="0.6", label="seen")
        ax.scatter(p[unseen, i], p[unseen, j], s=0.6, color="tab:red", label="not seen yet")
        tip = c + 1.3 * radius * np.asarray(up_W)
        arrows = [(tip, "tab:blue")]
        if toward_W is not None:
            arrows.append((c + 1.3 * radius * np.asarray(toward_W), "tab:orange"))
        for end, color in arrows:
            ax.annotate(
                "",
                xy=(end[i], end[j]),
                xytext=(c[i], c[j]),
                arrowprops=dict(arrowstyle="-|>", color=color, lw=2),
            )
            # The arrows lie partly outside the model: let the axes take them in.
            ax.update_datalim([(end[i], end[j]), (c[i], c[j])])
        ax.plot(clamp_W[i], clamp_W[j], marker="*", markersize=16, color="tab:green")
        ax.autoscale_view()
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel(f"{xl} (m)")
        ax.set_ylabel(f"{yl} (m)")
    axes[0].legend(markerscale=12, loc="lower left", fontsize=8)
    fig.suptitle(
        heading
        or f"Hanging {hanging + 1}: bring the side the blue arrow points to straight up, clamp at "
        "the green star; red: not seen yet"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
