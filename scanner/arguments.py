"""Argument types shared by the subcommands' parsers (they turn a bad value into argparse's usage
error naming the option, exit 2), and the options several subcommands have."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from reconstruction.errors import ScannerError


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text}")
    return v


def worker_count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if not 1 <= v <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"expected 1 to {MAX_WORKERS}, got {text}")
    return v


MAX_WORKERS = 1024


def path_arg(text: str) -> Path:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got an empty string")
    return Path(text)


def name_arg(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a name, got an empty string")
    return text


def for_flag(flag: str, apply: Callable):
    """`apply()` (a configuration change that validates itself), its ScannerError prefixed with
    the command-line flag that asked for it."""
    try:
        return apply()
    except ScannerError as e:
        raise ScannerError(f"{flag}: {e}") from None


def add_output_arguments(
    parser: argparse.ArgumentParser,
    out_help: str,
    force_help: str,
    *,
    required: bool = False,
    **out_options,
) -> None:
    """--out, where the command writes, and --force, which lets it replace what is there;
    `out_options` go to --out (argparse's dest, metavar)."""
    parser.add_argument("--out", type=path_arg, required=required, help=out_help, **out_options)
    parser.add_argument("--force", action="store_true", help=force_help)


def add_seed_argument(parser: argparse.ArgumentParser, default: int | None = None) -> None:
    """--seed of the simulated errors (robots.truth.ErrorModel)."""
    parser.add_argument(
        "--seed",
        type=int,
        default=default,
        help="seed of the simulated error model (default 0)",
    )


def add_driver_argument(parser: argparse.ArgumentParser, what: str, note: str = "") -> None:
    """--driver: real hardware instead of the Drake simulation (`what` runs on it; `note` ends
    the help)."""
    parser.add_argument(
        "--driver",
        type=name_arg,
        metavar="MODULE:FACTORY",
        help=f"{what} with real hardware: factory(config) returns robots.drivers.Hardware "
        f"(default: the Drake simulation){note}",
    )
