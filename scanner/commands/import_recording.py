"""The parser of `scanner import-recording SOURCE --out SCAN_DIR` (the runner:
scanner/recordings/import_command.py): a recording of another eye-in-hand system (IDR/NeuS,
COLMAP, or the plain YAML form) checked whole, then written as a scan directory."""

from __future__ import annotations

import argparse
import math

from scanner.commands.arguments import add_command, path_arg, positive_float

FORMAT_NAMES = ("idr", "colmap", "plain")


class KnownDistanceOption(argparse.Action):
    """--known-distance IMAGE_A IMAGE_B METRES, the distance a usage error when not a positive
    number of metres."""

    def __call__(self, parser, namespace, values, option_string=None):
        a, b, text = values
        try:
            metres = float(text)
        except ValueError:
            metres = math.nan
        if not (math.isfinite(metres) and metres > 0):
            parser.error(f"argument {option_string}: expected a distance in metres, got '{text}'")
        if a == b:
            parser.error(f"argument {option_string}: expected two different images, got {a} twice")
        setattr(namespace, self.dest, (a, b, metres))


def add_import_recording_parser(sub) -> None:
    imp = add_command(
        sub,
        "import-recording",
        "scanner.recordings.import_command:run_import_recording",
        help="make a scan directory from another system's recording (IDR/NeuS, COLMAP, plain)",
        description="Read a recording of images with camera poses (IDR/NeuS cameras_sphere.npz "
        "as DTU MVS is published, a COLMAP sparse model with its images, or the plain "
        "recording.yaml form), check it whole, and write it as a scan directory that "
        "`scanner reconstruct` reads. Nothing is written when any check fails.",
    )
    imp.add_argument(
        "source", type=path_arg, metavar="SOURCE", help="the recording's folder (or plain file)"
    )
    imp.add_argument(
        "--out",
        type=path_arg,
        required=True,
        metavar="SCAN_DIR",
        help="the scan directory to write: a new or empty folder (required, no default)",
    )
    imp.add_argument(
        "--format",
        choices=FORMAT_NAMES,
        help="idr, colmap or plain (default: recognised from SOURCE's files)",
    )
    imp.add_argument(
        "--scale",
        type=positive_float,
        metavar="F",
        help="metres per unit of the recording's lengths (default: idr 0.001, DTU's "
        "millimetres; colmap: required, or --known-distance; plain: unit_m in the file)",
    )
    imp.add_argument(
        "--known-distance",
        nargs=3,
        action=KnownDistanceOption,
        metavar=("IMAGE_A", "IMAGE_B", "METRES"),
        help="colmap: the distance in metres between the camera centres of two images (their "
        "names in the model), which sets the scale (default: none, --scale)",
    )
    imp.add_argument(
        "--masks",
        type=path_arg,
        metavar="DIR",
        help="object masks, one per image in the order of the images' names (default: idr "
        "SOURCE/mask/ when there; none otherwise)",
    )
    # The output rule asks for --force; an imported recording never replaces anything.
    imp.set_defaults(force=False)
