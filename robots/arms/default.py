"""Which arm the product drives: the one place that chooses it, from a configuration's `robot`
(a built-in arm's name, or the path of an arm file), and the arm used when none is named."""

from __future__ import annotations

from functools import cache
from pathlib import Path

from robots.arms.arm import Arm, load_arm
from robots.arms.rx60 import rx60_arm

DEFAULT_ARM: Arm = rx60_arm()
DEFAULT_ROBOT = "rx60"
# Arms built into the product by name (their kinematics are code, not a file).
BUILT_IN_ARMS: dict[str, Arm] = {DEFAULT_ROBOT: DEFAULT_ARM}


def is_arm_file(robot: str) -> bool:
    """`robot` names an arm file rather than a built-in arm."""
    return robot not in BUILT_IN_ARMS


def arm_of(robot: str) -> Arm:
    """The arm `robot` names: a built-in arm, or the arm file at that path (read once per
    process: its model is parsed and its limits checked). ScannerError, one line, when it is
    neither (the caller names the field or flag)."""
    if not is_arm_file(robot):
        return BUILT_IN_ARMS[robot]
    path = Path(robot)
    if not path.is_file():
        raise _not_an_arm(robot)
    return _arm_file(str(path.resolve()))


def _not_an_arm(robot: str):
    from reconstruction.common.errors import ScannerError

    names = ", ".join(repr(n) for n in BUILT_IN_ARMS)
    return ScannerError(f"expected {names} or the path of an arm file, got {robot!r}")


@cache
def _arm_file(path: str) -> Arm:
    return load_arm(path)
