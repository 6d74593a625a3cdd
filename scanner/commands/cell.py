"""`scanner check-cell` and `scanner emulate-controller`: a real cell checked before anything
moves, and the controller emulator to check a network and configuration against."""

from __future__ import annotations

import argparse

from scanner.commands.arguments import (
    ConfigDefault,
    add_command,
    add_config_file_argument,
    add_config_option,
    add_driver_argument,
    hangings_arg,
    name_arg,
    path_arg,
    positive_float,
)

# Exit code of a check that ran and found the cell not ready (as an inspection out of tolerance).
EXIT_NOT_READY = 4


def port_arg(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a TCP port number, got '{text}'") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port in [0, 65535], got {text}")
    return port


def add_check_cell_parser(sub) -> None:
    check = add_command(
        sub,
        "check-cell",
        "scanner.commands.cell:run_check_cell_command",
        help="check a real cell before scanning: robot link, controller, joints, camera, first "
        "move (nothing moves)",
        description="Connect to the robot controller and the camera of the configuration's "
        "hardware: section (or --driver), read the joints and the controller's status, grab "
        "one stereo pair and check it (size against the calibration, exposure, sharpness, the "
        "board with --board), plan the scan's first move from the measured joints, and print "
        f"a verdict per item. The arm never moves. Exit code 0 when a scan could start, "
        f"{EXIT_NOT_READY} when an item failed, 2 when the configuration does not fit the cell.",
    )
    add_config_file_argument(
        check,
        "the scan configuration (YAML) with the hardware: section to check (default: none; "
        "then --driver is required)",
    )
    check.add_argument(
        "--calibration",
        type=path_arg,
        help="the calibration file the scan will use (image size, X_FC) (default: the "
        "configuration's calibration_file)",
    )
    add_driver_argument(check, "check a cell")
    add_config_option(
        check,
        "--hangings",
        type=hangings_arg,
        metavar="N|auto",
        help="the hangings the scan will make, as scan's --hangings: with auto the driver "
        "must be able to ask the operator for a re-hang (default %(config_default)s)",
        config=ConfigDefault("scanner.configs.scan:ScanConfig", "hangings"),
    )
    check.add_argument(
        "--board",
        action="store_true",
        help="also require the calibration board (the calibrate command's default board) in "
        "both images (default: off)",
    )


def run_check_cell_command(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from reconstruction.common.errors import ScannerError
    from scanner.calibrate.config import CalibrateConfig
    from scanner.check_cell.check import check_cell
    from scanner.configs.scan import load_scan_config, with_overrides

    config = load_scan_config(args.config)
    if args.driver:
        config = replace(config, hardware=None)  # --driver stands for the hardware: section
    # As scan's flags: each checked (a bad file or driver named) before anything connects.
    config = with_overrides(
        config,
        calibration_file=None if args.calibration is None else str(args.calibration),
        driver=args.driver,
        hangings=args.hangings,
    )
    if config.hardware is None and not config.driver:
        raise ScannerError(
            "check-cell: no cell to check: give --config FILE with a hardware: section "
            "(see scanner/configs/hardware.yaml) or --driver MODULE:FACTORY"
        )
    board = CalibrateConfig().board if args.board else None
    items = check_cell(config, board, report=lambda item: print(item.line(), flush=True))
    failed = [item.name for item in items if not item.ok]
    if failed:
        print(f"NOT READY: {', '.join(dict.fromkeys(failed))} failed")
        return EXIT_NOT_READY
    print("READY: a scan can start")
    return 0


def add_emulate_parser(sub) -> None:
    from robots.emulator.val3_server import EmulatorSettings

    defaults = EmulatorSettings()
    emulate = add_command(
        sub,
        "emulate-controller",
        "scanner.commands.cell:run_emulate_command",
        help="emulate the RX60's controller (the ROS-Industrial VAL 3 server) on TCP ports",
        description="Serve the VAL 3 server's protocol (motion port: joint trajectory points "
        "answered and queued 10 deep; state port: joint positions at 50 Hz, status at 10 Hz) "
        "with an emulated RX60 that moves joint-linearly at each point's speed, so that a "
        "network, a configuration and check-cell can be tried before the real controller. "
        "Runs until Ctrl-C.",
    )
    emulate.add_argument(
        "--host",
        type=name_arg,
        default=defaults.host,
        help="address to listen on (default %(default)s; 0.0.0.0: every interface)",
    )
    emulate.add_argument(
        "--motion-port", type=port_arg, default=defaults.motion_port, help="(default %(default)s)"
    )
    emulate.add_argument(
        "--state-port", type=port_arg, default=defaults.state_port, help="(default %(default)s)"
    )
    emulate.add_argument(
        "--time-scale",
        type=positive_float,
        default=defaults.time_scale,
        help="emulated seconds per second: above 1 the arm moves faster than the real one "
        "(default %(default)s)",
    )


def run_emulate_command(args: argparse.Namespace) -> int:
    import time
    from dataclasses import replace

    from robots.emulator.val3_server import EmulatorSettings, Val3Emulator
    from robots.simulation.cell import HOME_Q

    settings = replace(
        EmulatorSettings(),
        host=args.host,
        motion_port=args.motion_port,
        state_port=args.state_port,
        time_scale=args.time_scale,
    )
    try:
        emulator = Val3Emulator(settings, HOME_Q).start()
    except OSError as e:
        from reconstruction.common.errors import ScannerError

        raise ScannerError(
            f"--motion-port/--state-port: cannot listen on {args.host} ({e.strerror or e})"
        ) from None
    with emulator:
        (host, motion), (_, state) = emulator.motion_address, emulator.state_address
        print(f"emulated VAL 3 controller on {host}: motion port {motion}, state port {state}")
        print(
            "hardware.robot in a scan configuration: " + f"{{host: {host}, motion_port: "
            f"{motion}, state_port: {state}}}; Ctrl-C stops",
            flush=True,
        )
        while True:
            time.sleep(1.0)
