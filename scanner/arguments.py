"""Argument types shared by the subcommands' parsers: they turn a bad value into argparse's usage
error naming the option (exit 2)."""

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
