"""What a recording's reconstruction reports: report.json's record of the recording, its volume,
table, pairs and measures, and summary.md."""

from __future__ import annotations

import math
from pathlib import Path

from scanner.scan_dir.captures import atomic_write_text


def recording_report(scan, views, paired, volume, table, result, measured, settings, voxel) -> dict:
    info = scan.recording
    pairs = [
        {
            "reference": views.indices[p.reference],
            "other": views.indices[p.other],
            "baseline_mm": round(1e3 * p.baseline_m, 2),
            "angle_deg": round(math.degrees(p.angle_rad), 2),
            "points": len(c.points_C),
            "epipolar_median_px_before": round(c.pose.before.median_px, 3),
            "epipolar_median_px": round(c.pose.after.median_px, 3),
            "pose_refined": c.pose.refined,
            "seconds": round(s, 2),
        }
        for p, c, s in zip(paired.pairs, paired.clouds, paired.seconds, strict=True)
        if p is not None
    ]
    masks = sum(m is not None for m in views.masks)
    return {
        "object": scan.manifest.get("object"),
        "status": "complete",
        "sensor": "one camera, stereo from pairs of its views",
        "recording": {
            **info.to_dict(),
            "masks_used": settings.masks if masks else "none (the recording has none)",
            "handeye": "not run: the recording gave camera poses"
            if info.camera_poses_given
            else ("run" if settings.reconstruction.handeye.enabled else "off"),
        },
        "working_volume": {
            "source": volume.source,
            "centre_m": [round(float(c), 6) for c in volume.centre_W],
            "radius_m": round(float(volume.radius_m), 6),
            **(
                {}
                if volume.half_extent_m is None
                else {"half_extent_m": [round(float(h), 6) for h in volume.half_extent_m]}
            ),
        },
        "table": None
        if table is None
        else {
            "normal_W": [round(float(c), 6) for c in table.normal_W],
            "offset_m": round(table.offset_m, 6),
            "share": round(table.share, 4),
        },
        "voxel_size_m": voxel,
        "captures_used": len(views.indices),
        "captures_skipped": [],
        "pairs": pairs,
        "pairs_refined": sum(p["pose_refined"] for p in pairs),
        "depth_views": sum(p is None for p in paired.pairs),
        "fused_points": len(result.fused.points_W),
        **measured,
    }


def write_recording_summary(report: dict, out: Path) -> Path:
    """summary.md: what was done with the recording and how well the model agrees with it."""
    rec = report["recording"]
    volume = report["working_volume"]
    lines = [
        f"# Model of the recording {report['object']}",
        "",
        f"- {rec['views']} views ({rec['format']}, {rec['metres_per_unit']:g} m per unit), "
        f"{len(report['pairs'])} pairs of one camera's views"
        + (
            f", {report['depth_views']} views from their own depth images"
            if report["depth_views"]
            else ""
        )
        + f"; masks used: {rec['masks_used']}.",
        f"- Hand-eye correction: {rec['handeye']}.",
        f"- Working volume from {volume['source']}: "
        + (
            f"radius {1e3 * volume['radius_m']:.1f} mm."
            if "half_extent_m" not in volume
            else "a box of "
            + " x ".join(f"{2e3 * h:.1f}" for h in volume["half_extent_m"])
            + " mm."
        ),
        "- Table: "
        + (
            "none found in the data."
            if report["table"] is None
            else f"found (a plane holding {100 * report['table']['share']:.0f} % of the "
            "points), removed."
        ),
        f"- Pairs whose relative pose was refined from the images: {report['pairs_refined']}.",
        "",
    ]
    s = report.get("silhouette")
    if s:
        where = (
            "views whose masks the model did not use"
            if s["held_out"]
            else "every view (their masks were used: not held out)"
        )
        m, c = s["mesh"], s["fused_cloud"]
        lines += [
            f"## Silhouettes ({len(s['views'])} {where})",
            "",
            f"- Model: IoU {m['iou_median']:.3f} median, {m['iou_worst']:.3f} worst "
            f"(view {m['iou_worst_view']}); mask pixels covered {m['coverage_median']:.3f} "
            f"median, {m['coverage_worst']:.3f} worst.",
            f"- Fused cloud: IoU {c['iou_median']:.3f} median, {c['iou_worst']:.3f} worst; "
            f"covered {c['coverage_median']:.3f} median.",
            "",
        ]
    h = report.get("split_half")
    if h:
        lines += [
            "## Split-half agreement (fused points of even vs odd reference views)",
            "",
            f"- {h['median_mm']} mm median, {h['p90_mm']} mm p90 on the common part "
            f"({100 * h['common_share']:.1f} % of the points within {h['common_radius_mm']} mm); "
            f"along the other half's surface normal {h.get('normal_median_mm')} mm median, "
            f"{h.get('normal_p90_mm')} mm p90 (the nearest point adds the two samplings' "
            "spacing).",
            "",
        ]
    picture = report.get("outputs", {}).get("colour_picture")
    if picture:
        lines += [f"![The model in the colours of its images]({picture})", ""]
    path = Path(out) / "summary.md"
    atomic_write_text(path, "\n".join(lines))
    return path
