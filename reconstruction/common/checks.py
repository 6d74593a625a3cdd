"""Validation of configuration fields, shared by every typed configuration.

Each check raises ScannerError naming the field as `section.name` (the key path a user writes in
YAML) with what was expected and what was given. A field states its bound where it is declared
(`voxel_m: float = positive(0.003)`) and `check_fields(section, self)` in `__post_init__` applies
every such bound in declaration order; bounds that depend on another field or are not a plain
range are checked by the `require_*` functions, or by hand, in `__post_init__`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable
from typing import Any

from reconstruction.common.errors import ScannerError

# The key under which a field's bounds are kept in its `dataclasses.field` metadata.
_BOUNDS = "scanner.bounds"


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_integer(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclasses.dataclass(frozen=True)
class _Bound:
    """What a field's value must be (`expected`, as the error says it) and the test for it."""

    expected: str
    holds: Callable[[Any], bool]

    def check(self, section: str, name: str, value) -> None:
        if not self.holds(value):
            raise ScannerError(f"{section}.{name}: expected {self.expected}, got {value!r}")


_POSITIVE = _Bound("a positive number", lambda v: _number(v) and v > 0)
_NON_NEGATIVE = _Bound("a non-negative number", lambda v: _number(v) and v >= 0)
_FRACTION = _Bound("a number in [0, 1]", lambda v: _number(v) and 0 <= v <= 1)


def _count_bound(minimum: int, maximum: int | None) -> _Bound:
    if maximum is None:
        return _Bound(f"an integer >= {minimum}", lambda v: _is_integer(v) and v >= minimum)
    return _Bound(
        f"an integer in [{minimum}, {maximum}]",
        lambda v: _is_integer(v) and minimum <= v <= maximum,
    )


def _at_most_bound(maximum: float) -> _Bound:
    return _Bound(f"a number <= {maximum:g}", lambda v: _number(v) and v <= maximum)


def _bounded(default, *bounds: _Bound) -> Any:
    return dataclasses.field(default=default, metadata={_BOUNDS: bounds})


# Each field declarer takes the field's default; without one the field is a required argument.
_REQUIRED: Any = dataclasses.MISSING


def positive(default: float = _REQUIRED, at_most: float | None = None) -> Any:
    """A field that must be a finite number > 0 (and <= at_most when given)."""
    if at_most is None:
        return _bounded(default, _POSITIVE)
    return _bounded(default, _POSITIVE, _at_most_bound(at_most))


def non_negative(default: float = _REQUIRED) -> Any:
    """A field that must be a finite number >= 0."""
    return _bounded(default, _NON_NEGATIVE)


def fraction(default: float = _REQUIRED) -> Any:
    """A field that must be a number in [0, 1]."""
    return _bounded(default, _FRACTION)


def integer(default: int = _REQUIRED, minimum: int = 1, maximum: int | None = None) -> Any:
    """A field that must be an integer >= minimum (and <= maximum when given)."""
    return _bounded(default, _count_bound(minimum, maximum))


def check_fields(section: str, config: object) -> None:
    """The bounds of every field declared with positive(), integer(), ..., in declaration order."""
    for f in dataclasses.fields(config):
        for bound in f.metadata.get(_BOUNDS, ()):
            bound.check(section, f.name, getattr(config, f.name))


def _require(section: str, config: object, names: Iterable[str], bound: _Bound) -> None:
    for name in names:
        bound.check(section, name, getattr(config, name))


def require_positive(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a finite number > 0."""
    _require(section, config, names, _POSITIVE)


def require_non_negative(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a finite number >= 0."""
    _require(section, config, names, _NON_NEGATIVE)


def require_count(
    section: str,
    config: object,
    names: Iterable[str],
    minimum: int = 1,
    maximum: int | None = None,
) -> None:
    """Each field an integer >= minimum (and <= maximum when given)."""
    _require(section, config, names, _count_bound(minimum, maximum))


def require_at_most(section: str, config: object, names: Iterable[str], maximum: float) -> None:
    """Each field a finite number <= maximum (a physical bound, e.g. what the robot reaches)."""
    _require(section, config, names, _at_most_bound(maximum))


def require_fraction(section: str, config: object, names: Iterable[str]) -> None:
    """Each field a number in [0, 1]."""
    _require(section, config, names, _FRACTION)


def require_choice(section: str, name: str, value: str, choices: Iterable[str]) -> None:
    """`value` one of `choices` (e.g. a method or mode chosen by name)."""
    choices = tuple(choices)
    if value not in choices:
        raise ScannerError(f"{section}.{name}: '{value}' is not one of {', '.join(choices)}")
