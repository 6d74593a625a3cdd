"""The `scanner` command line: one parser with a sub-parser per command (each registered by its
own package), the dispatch to the command's runner, and errors turned into one line and an exit
code."""

from __future__ import annotations

import argparse
import importlib
import sys

from reconstruction.common.errors import ScannerError
from reconstruction.common.memory import keep_freed_memory
from scanner.commands.arguments import ScannerArgumentParser
from scanner.commands.calibrate_arguments import add_calibrate_parser
from scanner.commands.cell import add_check_cell_parser, add_emulate_parser
from scanner.commands.exchange import add_export_parser, add_import_parser
from scanner.commands.import_recording import add_import_recording_parser
from scanner.commands.inspect import add_inspect_parser
from scanner.commands.monitor import add_monitor_parser
from scanner.commands.reconstruct import add_merge_parser, add_reconstruct_parser
from scanner.commands.scan import add_preview_parser, add_scan_parser
from scanner.commands.view import add_view_parser
from scanner.scan_dir.outputs import claim_output, command_output, input_paths
from scanner.scan_dir.results_folder import require_creatable


def build_parser() -> argparse.ArgumentParser:
    parser = ScannerArgumentParser(
        prog="scanner",
        description="Eye-in-hand 3D modelling with a Staubli RX60 and a wrist stereo camera. "
        "Runs in a Drake simulation unless a hardware driver is configured.",
    )
    parser.add_argument("--version", action="version", version=f"scanner {_version()}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=ScannerArgumentParser
    )
    add_scan_parser(sub)
    add_calibrate_parser(sub)
    add_reconstruct_parser(sub)
    add_merge_parser(sub)
    add_preview_parser(sub)
    add_export_parser(sub)
    add_import_parser(sub)
    add_import_recording_parser(sub)
    add_inspect_parser(sub)
    add_view_parser(sub)
    add_monitor_parser(sub)
    add_check_cell_parser(sub)
    add_emulate_parser(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("scanner")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """Each command's parser names its runner (`add_command(..., run="module:function")`),
    imported only now, so that building the parser stays light. What it writes to is checked
    first, the same way for every command (scanner.scan_dir.outputs)."""
    output = command_output(args)
    if output is not None:
        flag, out, kind = output
        claim_output(flag, out, kind, args.force, input_paths(args, _flags(parser, args)))
        require_creatable(out.parent if kind.is_file else out, flag)
    module, function = args.run.split(":")
    return getattr(importlib.import_module(module), function)(args)


def _flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, str]:
    """argparse dest -> the words a user typed for it (the long option, or the metavar of a
    positional argument), in the chosen subcommand's parser."""
    chosen = parser._parser_of(args)
    flags = {}
    for action in chosen._actions:
        if action.option_strings:
            flags[action.dest] = max(action.option_strings, key=len)
        else:
            flags[action.dest] = action.metavar or action.dest.upper()
    return flags


def _quiet_libraries() -> None:
    """Library chatter stays off the console: OpenCV and Open3D failures surface as our
    messages (their results are checked), Drake's context allocation is logged at INFO."""
    import logging

    import cv2
    import open3d as o3d
    import pydrake.common  # noqa: F401  (sets up the "drake" logger, which we then quieten)

    logging.getLogger("drake").setLevel(logging.WARNING)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)


def main(argv: list[str] | None = None) -> int:
    keep_freed_memory()
    parser = build_parser()
    args = parser.parse_args(argv)
    _quiet_libraries()
    try:
        return _run(args, parser)
    except ScannerError as e:
        message = " ".join(str(e).split())  # one line, whatever a library put into it
        print(f"scanner: error: {message}", file=sys.stderr)
        return e.exit_code
    except OSError as e:
        # Reading or writing failed where no stage turned it into a message of its own.
        where = f"{e.filename}: " if e.filename else ""
        print(f"scanner: error: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("scanner: interrupted", file=sys.stderr)
        return 130
