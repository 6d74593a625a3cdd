"""The command-line arguments of `scanner reconstruct` and `scanner merge` (kept free of heavy
imports: the parser is built for every command, `--help` included)."""

from __future__ import annotations

from scanner.commands.arguments import (
    ConfigDefault,
    add_command,
    add_config_file_argument,
    add_config_option,
    add_output_arguments,
    mesh_formats_arg,
    name_arg,
    path_arg,
    show_formats,
    worker_count,
)

# Where reconstruct's flags take their defaults from when neither they nor --config give a value.
PROCESSING_CONFIG = "scanner.configs.scan:ProcessingConfig"


def add_reconstruct_parser(sub) -> None:
    reconstruct = add_command(
        sub,
        "reconstruct",
        "scanner.commands.reconstruct:run_reconstruct_command",
        help="re-run the reconstruction offline on a saved scan directory",
        description="Rebuild the model from saved captures (never modifies them).",
    )
    reconstruct.add_argument(
        "scan_dirs",
        type=path_arg,
        nargs="+",
        metavar="SCAN_DIR",
        help="scan directories made by `scanner scan`; several are reconstructed in parallel "
        "as Ray tasks, each into its own SCAN_DIR/results[-N]",
    )
    add_config_file_argument(
        reconstruct,
        "processing YAML (stereo:, reconstruction:, ...) (default: the scan's own settings)",
    )
    reconstruct.add_argument(
        "--calibration",
        type=path_arg,
        help="use this calibration's stereo model and X_FC instead of the scan's (default: the "
        "scan's own)",
    )
    add_output_arguments(
        reconstruct,
        "results folder (default SCAN_DIR/results, or results-N when that holds one already)",
        "replace the reconstruction already in --out",
    )
    reconstruct.add_argument(
        "--no-icp",
        action="store_true",
        help="poses from the robot only (default: off, ICP as the settings say)",
    )
    reconstruct.add_argument(
        "--no-handeye",
        action="store_true",
        help="keep X_FC as given, no loop-based correction (default: off, as the settings say)",
    )
    reconstruct.add_argument(
        "--workers",
        type=worker_count,
        help="scans reconstructed at a time (default: the number of CPU cores)",
    )
    reconstruct.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="run the tasks on this Ray cluster (HOST:PORT, or auto) instead of a local Ray; "
        "its nodes need scanner installed and the scans at the same paths (default: local)",
    )
    add_config_option(
        reconstruct,
        "--formats",
        type=mesh_formats_arg,
        help="mesh file formats, comma separated from ply,obj,stl (default %(config_default)s, "
        "or what the scan's or --config's processing.mesh_formats says)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_formats", show_formats),
    )
    add_config_option(
        reconstruct,
        "--units",
        type=name_arg,
        metavar="{m,mm}",
        help="unit of the mesh files' coordinates; not metres: the file names end in _mm "
        "(default: the settings' processing.mesh_export.units, %(config_default)s unless "
        "configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.units"),
    )
    add_config_option(
        reconstruct,
        "--frame",
        type=name_arg,
        metavar="{world,object}",
        help="frame of the mesh files: the robot's world, or object (centred on the surface, "
        "along its principal axes; file names end in _object); mesh_export.yaml gives X_WO "
        "(default: the settings' processing.mesh_export.frame, %(config_default)s unless "
        "configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.frame"),
    )
    add_config_option(
        reconstruct,
        "--decimate",
        type=int,
        metavar="N",
        help="at most N triangles per mesh file (quadric decimation; the Hausdorff distance to "
        "the full mesh is reported) (default: the settings' "
        "processing.mesh_export.decimate_triangles, %(config_default)s unless configured)",
        config=ConfigDefault(PROCESSING_CONFIG, "mesh_export.decimate_triangles", _no_decimation),
    )


def _no_decimation(value) -> str:
    return "no decimation" if value is None else str(value)


def add_merge_parser(sub) -> None:
    merge = add_command(
        sub,
        "merge",
        "scanner.commands.reconstruct:run_merge_command",
        help="align and merge scans of one object (e.g. hung differently) into one model",
        description="Align the passes of two or more scan directories (each of one or more "
        "hangings) into the first one's frame, verify every alignment, and build one model. "
        "An alignment that fails verification writes nothing and exits with code 3.",
    )
    merge.add_argument("scan_dirs", type=path_arg, nargs="+", metavar="SCAN_DIR")
    add_config_file_argument(merge, "processing YAML (default: the first scan's settings)")
    add_output_arguments(
        merge,
        "results folder to create (required, no default)",
        "replace the merged model already in --out",
        required=True,
    )
