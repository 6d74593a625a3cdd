"""Hardware driver modules for the turntable tests, loaded with `--driver
tests.turntable_hardware:FACTORY` like a real cell's: the simulator's arm and camera beside a
turntable that answers, reports another angle than it was told, or does not answer."""

from __future__ import annotations

from robots.drivers.interfaces import Hardware, TurntableDriver
from scanner.scan.world import simulated_cell

# The simulated cells the factories made (the tests check that their arm never moved).
CELLS: list = []
# `slipping`: how many commands the turntable follows before it slips (None: it never does).
SLIP_AFTER: int | None = 1
# How far a lying or slipping turntable's reported angle is off (rad): a lost belt tooth.
OFF_RAD = 0.3


class FakeTurntable(TurntableDriver):
    def __init__(self, off_after: int | None = None, silent: bool = False) -> None:
        self.angle, self.commands = 0.0, 0
        self.off_after, self.silent = off_after, silent

    def rotate_to(self, angle_rad: float) -> None:
        self.angle, self.commands = float(angle_rad), self.commands + 1

    def angle_rad(self) -> float:
        if self.silent:
            raise TimeoutError("no reply from the turntable within 1 s")
        off = self.off_after is not None and self.commands > self.off_after
        return self.angle + (OFF_RAD if off else 0.0)


def _hardware(config, turntable: FakeTurntable) -> Hardware:
    sim = simulated_cell(config)
    CELLS.append(sim)
    return Hardware(sim.robot, sim.camera, turntable=turntable)


def lying(config) -> Hardware:
    """Reports another angle than every one it is told."""
    return _hardware(config, FakeTurntable(off_after=0))


def silent(config) -> Hardware:
    """Never answers."""
    return _hardware(config, FakeTurntable(silent=True))


def slipping(config) -> Hardware:
    """Follows its first SLIP_AFTER commands, then reports another angle."""
    return _hardware(config, FakeTurntable(off_after=SLIP_AFTER))


def no_turntable(config) -> Hardware:
    return _hardware(config, None)
