"""Validation of configuration fields, shared by every typed configuration.

Each check raises ScannerError naming the field as `section.name` (the key path a user writes in
YAML) with what was expected and what was given; configurations call them from __post_init__.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from reconstruction.errors import ScannerError


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _fail(section: str, name: str, expected: str, value) -> None:
    raise ScannerError(f"{section}.{name}: expected {expected}, got {value!r}")


def require_positive(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a finite number > 0."""
    for name in names:
        value = getattr(config, name)
        if not (_number(value) and value > 0):
            _fail(section, name, "a positive number", value)


def require_non_negative(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a finite number >= 0."""
    for name in names:
        value = getattr(config, name)
        if not (_number(value) and value >= 0):
            _fail(section, name, "a non-negative number", value)


def require_count(
    section: str,
    config: object,
    names: Iterable[str],
    minimum: int = 1,
    maximum: int | None = None,
) -> None:
    """Each field an integer >= minimum (and <= maximum when given)."""
    for name in names:
        value = getattr(config, name)
        ok = isinstance(value, int) and not isinstance(value, bool) and value >= minimum
        if maximum is None and not ok:
            _fail(section, name, f"an integer >= {minimum}", value)
        if maximum is not None and not (ok and value <= maximum):
            _fail(section, name, f"an integer in [{minimum}, {maximum}]", value)


def require_at_most(section: str, config: object, names: Iterable[str], maximum: float) -> None:
    """Each field a finite number <= maximum (a physical bound, e.g. what the robot reaches)."""
    for name in names:
        value = getattr(config, name)
        if not (_number(value) and value <= maximum):
            _fail(section, name, f"a number <= {maximum:g}", value)


def require_fraction(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a number in [0, 1]."""
    for name in names:
        value = getattr(config, name)
        if not (_number(value) and 0 <= value <= 1):
            _fail(section, name, "a number in [0, 1]", value)


def require_choice(section: str, name: str, value: str, choices: Iterable[str]) -> None:
    """`value` one of `choices` (e.g. a method or mode chosen by name)."""
    choices = tuple(choices)
    if value not in choices:
        raise ScannerError(f"{section}.{name}: '{value}' is not one of {', '.join(choices)}")
