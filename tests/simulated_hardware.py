"""A hardware driver module for the tests: the simulator's arm and camera, loaded through
`--driver tests.simulated_hardware:connect` exactly like a real robot's driver would be."""

from robots.drivers.interfaces import Hardware
from scanner.scan.world import simulated_cell


def connect(config) -> Hardware:
    """The scan cell of `scanner scan --driver tests.simulated_hardware:connect`."""
    sim = simulated_cell(config)
    return Hardware(sim.robot, sim.camera)


def not_hardware(config):
    return "a robot"


def connect_board_cell(config) -> Hardware:
    """The calibration cell (board on its stand) of `scanner calibrate --driver ...`."""
    from dataclasses import replace

    from scanner.calibrate.eye_in_hand import build_world

    world = build_world(replace(config, driver=None))
    return Hardware(world.robot, world.camera)
