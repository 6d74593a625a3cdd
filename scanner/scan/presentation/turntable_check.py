"""Whether a turntable does what it is told: it answers, and reports the angle it was commanded.
Checked before anything moves (`check_turntable`: a user error, exit 2) and after every turn
of a scan (`turn`; a failure there stops the scan, `TurntableStoppedError`, exit 5)."""

from __future__ import annotations

import math

from reconstruction.common.errors import ScannerError
from robots.drivers.interfaces import TurntableDriver
from scanner.scan.presentation.next_turn import wrapped

# How far the reported angle may be from the commanded one: a stepper turntable repeats to a
# few hundredths of a degree; 0.2 deg is a missed step or a slipping belt, not noise.
ANGLE_TOLERANCE_RAD = math.radians(0.2)


class TurntableStoppedError(ScannerError):
    """The turntable failed during a scan; the scan ends as interrupted and can be resumed."""

    exit_code = 5


def _mismatch(commanded_rad: float, reported_rad: float) -> str | None:
    """Why the reported angle is not the commanded one (None: it is)."""
    if not math.isfinite(reported_rad):
        return f"the turntable reports angle {reported_rad} after being told {_deg(commanded_rad)}"
    if abs(wrapped(reported_rad - commanded_rad)) > ANGLE_TOLERANCE_RAD:
        return (
            f"the turntable reports {_deg(reported_rad)} after being told {_deg(commanded_rad)} "
            f"(tolerance {math.degrees(ANGLE_TOLERANCE_RAD):g} deg)"
        )
    return None


def _deg(angle_rad: float) -> str:
    return f"{math.degrees(angle_rad):.2f} deg"


def turn(turntable: TurntableDriver, angle_rad: float) -> tuple[float | None, str | None]:
    """Command `angle_rad` and read it back: (reported angle, None) or (None, what failed). A
    driver that does not answer raises (its own time-out)."""
    try:
        turntable.rotate_to(angle_rad)
        reported = float(turntable.angle_rad())
    except Exception as e:  # any driver failure is the turntable's, told in one line
        return None, f"the turntable did not answer ({type(e).__name__}: {e})"
    problem = _mismatch(angle_rad, reported)
    return (None, problem) if problem else (reported, None)


def check_turntable(turntable: TurntableDriver | None) -> None:
    """Before anything moves: the cell has a turntable, it answers, and it reports the angle
    it is told (told to stay where it is, so nothing turns)."""
    if turntable is None:
        raise ScannerError(
            "presentation: turntable needs a driver with a turntable (Hardware.turntable is "
            "None); scan with presentation: hanging"
        )
    try:
        now = float(turntable.angle_rad())
    except Exception as e:
        raise ScannerError(
            f"turntable: the driver's turntable did not answer ({type(e).__name__}: {e}); "
            "nothing was moved"
        ) from None
    _, problem = turn(turntable, now)
    if problem:
        raise ScannerError(f"turntable: {problem}; nothing was moved")
