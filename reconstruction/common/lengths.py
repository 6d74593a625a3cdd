"""Lengths as users type them: a number in metres (the unit of every setting), or a number with a
unit suffix (`0.5mm`, `0.0005m`, `50um`).

A bare number is read in metres as documented; where that reading is implausible for what the
length measures (a tolerance larger than the part, anything under a micrometre, which no stereo
rig or robot of this class resolves), the refusal gives both readings (metres, and millimetres,
the unit a bare number was most likely meant in), so the fix is obvious.
"""

from __future__ import annotations

import math
import re

from reconstruction.common.errors import ScannerError

# Metres per unit suffix.
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "um": 1e-6, "µm": 1e-6}
# The shortest length anything here measures or resolves: a micrometre.
SMALLEST_M = 1e-6

_LENGTH = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ]*)\s*")


def parse_length(text: str) -> float:
    """Metres from `text`: a positive finite number in metres, or one with a unit suffix of
    UNITS_M; a ScannerError saying what is expected otherwise, or when under a micrometre."""
    m = _LENGTH.fullmatch(str(text))
    if not m or m.group(2) not in ("", *UNITS_M):
        raise ScannerError(
            f"expected a length such as 0.0005 (metres) or 0.5mm (units: "
            f"{', '.join(UNITS_M)}), got '{text}'"
        )
    value = float(m.group(1)) * UNITS_M[m.group(2) or "m"]
    if not (math.isfinite(value) and value > 0):
        raise ScannerError(f"expected a positive length, got '{text}'")
    if value < SMALLEST_M:
        raise ScannerError(
            f"'{text}' is {readings(value)}: under a micrometre, which nothing here resolves; "
            "give the unit (e.g. 0.5mm)"
        )
    return value


def readings(length_m: float) -> str:
    """`length_m` in metres and in millimetres: '0.5 m (500 mm)'."""
    return f"{length_m:g} m ({1e3 * length_m:g} mm)"


def bare_number(text: str) -> bool:
    """Whether `text` gave no unit (it was read in metres)."""
    m = _LENGTH.fullmatch(str(text))
    return bool(m) and not m.group(2)


def require_below(name: str, text: str, length_m: float, limit_m: float, what: str) -> None:
    """Refuse the length `name` (e.g. '--tolerance'), typed as `text` and read as `length_m`,
    at or beyond `limit_m`, `what` saying how it compares (e.g. "not less than the model's
    size"); for a bare number the message also gives its reading in millimetres."""
    if length_m < limit_m:
        return
    meant = ""
    if bare_number(text):
        typed = str(text).strip()
        meant = f"; if {typed} mm was meant, write {typed}mm ({1e-3 * length_m:g} m)"
    raise ScannerError(
        f"{name}: {text} reads as {readings(length_m)}, {what} ({readings(limit_m)}){meant}"
    )
