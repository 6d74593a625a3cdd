"""A recording's model.html: the model coloured by its distance to the measurements, as for a
scan without truth, and the views' frustums; no cell, no arm."""

from __future__ import annotations

import json
from pathlib import Path

from reconstruction.pipeline import ReconstructionResult
from scanner.recordings.views import RecordedViews
from scanner.scan_dir.captures import atomic_write_text


def recording_scene(result: ReconstructionResult, views: RecordedViews, settings):
    """model.html's scene of a recording's model: the mesh coloured by its distance to the
    fused measurements (as a scan without truth), the views' frustums; no cell, no arm."""
    from scanner.reconstruct.model_scene import colouring, headline_mesh
    from scanner.reports.model_page_layers import DisplayMesh, ModelScene, ViewFrustum, decimated

    mesh = headline_mesh(result, settings.primary_surface)
    if mesh is None:
        return None
    vertices, triangles = decimated(mesh.vertices, mesh.triangles)
    colours = colouring(vertices, result, None, None)
    return ModelScene(
        mesh=DisplayMesh(vertices, triangles, colours.values_m),
        scale_m=colours.scale_m,
        colour_meaning=f"{mesh.name} mesh: {colours.meaning}",
        signed=colours.signed,
        frustums=tuple(ViewFrustum(X) for X in views.X_WC),
        camera=views.cameras[0],
    )


def add_recording_page(
    result: ReconstructionResult, report: dict, out: Path, views: RecordedViews, settings
) -> dict:
    """model.html beside the finished results in `out`, linked from report.json; the report
    with the link (unchanged when the page could not be written: a warning, the results are
    complete without it)."""
    from scanner.reconstruct.model_scene import write_reconstruction_page
    from scanner.reports.model_page import PAGE_NAME

    seconds = write_reconstruction_page(out, lambda: recording_scene(result, views, settings))
    if seconds is None:
        return report
    report = {**report, "model_page": PAGE_NAME, "model_page_s": seconds}
    atomic_write_text(out / "report.json", json.dumps(report, indent=2) + "\n")
    return report
