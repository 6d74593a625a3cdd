"""A reconstruction result as files (fused cloud, meshes) and as a plain record for reports
(SI units; matrices as nested lists)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import yaml

from reconstruction.common.transforms import pose_difference
from reconstruction.pipeline import ReconstructionResult
from reconstruction.surfaces.export import (
    MeshExportConfig,
    MeshExports,
    export_record,
    prepare_exports,
)
from reconstruction.surfaces.fused import save_cloud
from reconstruction.surfaces.meshes import save_mesh
from reconstruction.surfaces.topology import mesh_quality

# Beside the meshes: their unit, frame and decimation (a reader of an STL has no other way to
# know them).
MESH_EXPORT_FILE = "mesh_export.yaml"


def _quality_record(quality, longest: int = 10) -> dict:
    """Mesh topology for the report; only the longest boundary loops (the rim, big holes)."""
    record = dict(vars(quality))
    loops = record.pop("boundary_loops_m")
    record["boundary_loops"] = len(loops)
    record["longest_boundary_loops_m"] = list(loops[:longest])
    return record


def summary(result: ReconstructionResult) -> dict:
    """A plain, YAML/JSON-ready record of the result (SI units; matrices as nested lists)."""
    he = result.handeye
    dt, dr = pose_difference(result.X_FC_nominal, result.X_FC)
    out: dict = {
        "views": [
            {
                "index": v.index,
                "points": v.counts.after_outliers,
                "X_WC": v.X_WC.tolist(),
                "X_WC_kinematic": v.X_WC_kinematic.tolist(),
            }
            for v in result.views
        ],
        "skipped_views": [{"index": i, "reason": why} for i, why in result.skipped_views],
        "edges": [
            {
                "source": e.source,
                "target": e.target,
                "kind": e.kind,
                "fitness": e.fitness,
                "inlier_rmse_m": e.inlier_rmse_m,
                "status": e.status,
                "residual_translation_m": e.residual_translation_m,
                "residual_rotation_rad": e.residual_rotation_rad,
            }
            for e in result.edges
        ],
        "X_FC_nominal": result.X_FC_nominal.tolist(),
        "X_FC": result.X_FC.tolist(),
        "X_FC_change_translation_m": dt,
        "X_FC_change_rotation_rad": dr,
        "fused_points": len(result.fused),
        "meshes": {
            name: {
                **_quality_record(mesh_quality(m)),
                "filled_holes": m.filled_holes,
                "filled_area_m2": m.filled_area_m2,
            }
            for name, m in result.meshes.items()
        },
        "timings_s": result.timings_s,
        "notes": list(result.notes),
    }
    if he is not None:
        out["handeye"] = {
            "source": he.source,
            "axxb": {
                name: {
                    "X_FC": s.X_FC.tolist(),
                    "rms_translation_m": s.rms_translation_m,
                    "rms_rotation_rad": s.rms_rotation_rad,
                    "rejected_views": list(s.rejected_views),
                    "error": s.error,
                }
                for name, s in he.axxb.items()
            },
        }
        for name, r in (("coarse", he.coarse), ("refinement", he.refinement)):
            if r is not None:
                out["handeye"][name] = _fit_record(r)
        d = he.diagnosis
        out["handeye_converged"] = d.converged
        out["handeye"]["diagnosis"] = {
            "converged": d.converged,
            "match_fraction": d.match_fraction,
            "match_rms_m": d.match_rms_m,
            "axxb_disagreement_m": d.axxb_disagreement_m,
            "axxb_disagreement_rad": d.axxb_disagreement_rad,
            "last_change_m": d.last_change_m,
            "last_change_rad": d.last_change_rad,
            # The accuracy the correction states: the expected (RMS) error of the camera's
            # origin and orientation in X_FC (see HandEyeRefinement).
            "sigma_translation_m": d.sigma_translation_m,
            "sigma_rotation_rad": d.sigma_rotation_rad,
            "failures": list(d.failures),
        }
    return out


def _fit_record(r) -> dict:
    return {
        "X_FC": r.X_FC.tolist(),
        "rms_before_m": r.rms_before_m,
        "rms_after_m": r.rms_after_m,
        "matches": r.n_matches,
        "match_fraction": r.match_fraction,
        "iterations": r.iterations,
        "converged": r.converged,
        "formal_std": r.formal_std.tolist(),
        "jackknife_std": r.jackknife_std.tolist(),
        "sigma_translation_m": r.sigma_translation_m,
        "sigma_rotation_rad": r.sigma_rotation_rad,
        "last_step_m": r.last_step_m,
        "last_step_rad": r.last_step_rad,
        "weakest_mode": r.weakest_mode.tolist(),
        "weakest_sensitivity": r.weakest_sensitivity,
    }


def export_files(exports: MeshExports, mesh_suffixes: Sequence[str]) -> dict[str, list[str]]:
    """File names of each exported mesh, by mesh name."""
    return {
        e.name: [f"{exports.file_stem(e.name)}{suffix}" for suffix in mesh_suffixes]
        for e in exports.meshes
    }


def save_outputs(
    result: ReconstructionResult,
    directory: Path,
    mesh_suffixes: Sequence[str] = (".ply",),
    exports: MeshExports | None = None,
) -> dict[str, Path]:
    """Write fused_cloud.ply, each exported mesh in each format (default: every mesh as it is,
    metres in W, mesh_<method><suffix>) and mesh_export.yaml, which states the meshes' unit,
    frame (X_WO) and decimation; returns the paths by name."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    exports = exports or prepare_exports(result.meshes, MeshExportConfig())
    paths = {"fused_cloud": directory / "fused_cloud.ply"}
    save_cloud(result.fused, paths["fused_cloud"])
    if result.fused_nominal is not None:
        paths["fused_cloud_nominal"] = directory / "fused_cloud_nominal.ply"
        save_cloud(result.fused_nominal, paths["fused_cloud_nominal"])
    files = export_files(exports, mesh_suffixes)
    for exported in exports.meshes:
        for name in files[exported.name]:
            paths[name] = directory / name
            save_mesh(exported.mesh, paths[name])
    paths["mesh_export"] = directory / MESH_EXPORT_FILE
    text = yaml.safe_dump(export_record(exports, files), sort_keys=False)
    paths["mesh_export"].write_text(text)
    return paths
