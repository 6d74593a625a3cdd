"""The command-line arguments of `scanner scan` and `scanner preview` (kept free of heavy
imports: the parser is built for every command, `--help` included)."""

from __future__ import annotations

from pathlib import Path

from scanner.commands.arguments import (
    ConfigDefault,
    add_command,
    add_config_file_argument,
    add_config_option,
    add_driver_argument,
    add_output_arguments,
    add_seed_argument,
    name_arg,
    path_arg,
    positive_float,
    seconds_list,
)

BUILTIN_HELP = "vase, bracket, pebble"
# Where scan's flags take their defaults from when neither they nor --config give a value.
SCAN_CONFIG = "scanner.configs.scan:ScanConfig"


def add_scan_parser(sub) -> None:
    scan = add_command(
        sub,
        "scan",
        "scanner.commands.scan:run_scan_command",
        help="scan an object: plan viewpoints, move, capture stereo pairs, reconstruct",
        description="Scan an object in the simulated work cell: viewpoints on a sphere around it, "
        "collision-free motions, stereo captures saved to a scan directory, then reconstruction.",
    )
    add_config_option(
        scan,
        "--object",
        type=name_arg,
        help=f"built-in object ({BUILTIN_HELP}), a mesh file (.obj/.ply/.stl), or the name of "
        "a mesh in a folder of $SCANNER_MESH_PATH (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "object"),
    )
    add_config_option(
        scan,
        "--size",
        type=positive_float,
        help="largest extent of the object in metres (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "cell.object_size_m"),
    )
    add_config_option(
        scan,
        "--views",
        type=int,
        help="number of views (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.count"),
    )
    add_config_option(
        scan,
        "--radius",
        type=positive_float,
        help="distance of the rig from the scan centre in metres (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.radius_m"),
    )
    add_output_arguments(
        scan,
        "scan directory to create (default scans/OBJECT-TIMESTAMP)",
        "replace an existing scan directory given with --out",
    )
    add_seed_argument(scan)
    add_config_option(
        scan,
        "--max-extra-views",
        type=int,
        metavar="K",
        help="after each hanging's planned views, up to K next-best views where the model so "
        "far leaves the most surface unseen (default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "views.max_extra_views"),
    )
    add_config_option(
        scan,
        "--hangings",
        type=int,
        help="passes over the object, re-hung between them (the simulator turns it; on "
        "hardware the operator is asked), aligned and merged into one model "
        "(default %(config_default)s)",
        config=ConfigDefault(SCAN_CONFIG, "hangings"),
    )
    scan.add_argument(
        "--monitor",
        action="store_true",
        help="watch the cell with the static stereo camera while scanning: an intrusion stops "
        "the arm and holds captures until the cell is clear (default: off, or monitor.enabled)",
    )
    scan.add_argument(
        "--intruder",
        type=seconds_list,
        metavar="SECONDS[,SECONDS...]",
        help="simulation with --monitor: a forearm reaches into the cell at these times (s on "
        "the monitor's clock) (default: none)",
    )
    add_config_file_argument(
        scan,
        "scan configuration YAML; flags given win over it (default: none, the built-in "
        "defaults stated here)",
    )
    scan.add_argument(
        "--calibration",
        type=path_arg,
        help="calibration file from `scanner calibrate` (stereo model and hand-eye X_FC) "
        "(default: the --config file's calibration_file, else the nominal camera and mount)",
    )
    add_driver_argument(scan, "scan")
    scan.add_argument(
        "--resume",
        type=path_arg,
        metavar="DIR",
        help="continue an interrupted scan (default: none, start a new scan)",
    )
    scan.add_argument(
        "--meshcat",
        action="store_true",
        help="show the robot, planned paths and the growing cloud live in Drake's Meshcat "
        "(default: off)",
    )
    scan.add_argument(
        "--print-config",
        action="store_true",
        help="print the effective configuration (defaults, --config, flags) as YAML and exit "
        "(default: off)",
    )
    scan.add_argument(
        "--plan-only",
        action="store_true",
        help="plan the views, tour and motions without moving the robot or capturing: writes "
        "plan.json and plan.png to --out (default scans/OBJECT-TIMESTAMP-plan) and lists the "
        "unreachable views (default: off)",
    )


def add_preview_parser(sub) -> None:
    preview = add_command(
        sub,
        "preview",
        "scanner.commands.scan:run_preview_command",
        help="render the simulated work cell and one stereo pair to PNG files",
        description="Build the simulated cell with an object, move the arm to one reachable "
        "viewpoint and render an overview and the stereo pair (with lens distortion and noise).",
    )
    preview.add_argument(
        "--object",
        default="vase",
        help=f"built-in object ({BUILTIN_HELP}) or a mesh file (default %(default)s)",
    )
    preview.add_argument(
        "--out",
        type=path_arg,
        default=Path("out/preview"),
        help="output folder (default %(default)s)",
    )
    add_seed_argument(preview, default=0)
