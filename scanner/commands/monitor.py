"""`scanner monitor`: watch the cell alone (the arm at rest) for a given time, e.g. to check
the static camera and the monitored volume before scanning."""

from __future__ import annotations

import argparse

from scanner.commands.arguments import (
    add_command,
    add_config_file_argument,
    positive_float,
    seconds_list,
)

DEFAULT_DURATION_S = 10.0


def add_monitor_parser(sub) -> None:
    monitor = add_command(
        sub,
        "monitor",
        "scanner.commands.monitor:run_monitor_command",
        help="watch the cell with the static stereo camera for a while and report intrusions",
        description="Watch the simulated cell (arm at rest) with the static stereo camera: "
        "background model, robot pixels removed by its geometry, stereo confirmation inside "
        "the monitored volume. Prints every event and the monitor's figures.",
    )
    monitor.add_argument(
        "--duration",
        type=positive_float,
        default=DEFAULT_DURATION_S,
        metavar="SECONDS",
        help="how long to watch, on the monitor's clock (default %(default)s)",
    )
    monitor.add_argument(
        "--intruder",
        type=seconds_list,
        metavar="SECONDS[,SECONDS...]",
        help="simulation: a forearm reaches into the cell at these times (default: none)",
    )
    add_config_file_argument(
        monitor,
        "scan configuration YAML: its monitor: section and cell (default: none, the "
        "built-in defaults)",
    )


def run_monitor_command(args: argparse.Namespace) -> int:
    from reconstruction.common.errors import ScannerError
    from scanner.configs.scan import load_scan_config, with_overrides
    from scanner.monitor.scan_monitor import ScanMonitor
    from scanner.scan.world import setup_world

    config = with_overrides(
        load_scan_config(args.config), monitor=True, intruder_start_s=args.intruder
    )
    late = [t for t in config.monitor.intruder_start_s if t >= args.duration]
    if late:
        raise ScannerError(
            f"--intruder: {', '.join(f'{t:g}' for t in late)} s is not within --duration "
            f"{args.duration:g} s"
        )
    world = setup_world(config, None, 0)
    session = ScanMonitor(config.monitor, world.planner.arm)
    session.start(world)
    monitor = session.monitors[-1]
    q = world.robot.joint_positions()
    # Within half a frame of the end the video holds no further frame.
    while monitor.video.clock_s < args.duration - 0.5 / monitor.fps:
        monitor.watch_rest(q, args.duration - monitor.video.clock_s)
    report = session.report()
    for e in report["events"]:
        print(f"t = {e['t_s']:.2f} s: {e['kind']} {e['detail']}")
    print(
        f"monitor: {report['frames']} frames over {report['video_s']:.1f} s, processed at "
        f"{report['fps_processed']:.0f} frames/s (needs {report['fps']:g}); intrusions "
        f"{report['detected']} of {report['intrusions']} detected, {report['false_alarms']} "
        "false alarms"
    )
    return 0
