"""A hardware driver module for the tests: the simulator's arm and camera, loaded through
`--driver tests.simulated_hardware:connect` exactly like a real robot's driver would be."""

from robots import camera_tool
from robots.drivers import Hardware
from robots.simulation import create_simulation


def connect(config) -> Hardware:
    design = config.camera.stereo_camera()
    sim = create_simulation(
        config.cell,
        config.object,
        config.error_model,
        design,
        camera_tool.nominal_X_FC(design.baseline_m),
    )
    return Hardware(sim.robot, sim.camera)


def not_hardware(config):
    return "a robot"


def connect_board_cell(config) -> Hardware:
    """The calibration cell (board on its stand) of `scanner calibrate --driver ...`."""
    from dataclasses import replace

    from scanner.calibrate_sim import build_world

    world = build_world(replace(config, driver=None))
    return Hardware(world.robot, world.camera)
