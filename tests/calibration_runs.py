"""The rendered eye-in-hand calibrations several test files read, each built once per test run by
whichever pytest-xdist worker asks first (`built_once`) and read back from disk by the others.

- `eight_stations`: 8 stations at the product's full resolution (1280x960), the default error
  model; accurate against the simulator's truth (measured 0.12 mm / 0.011 deg). The default 20
  stations' figures are scripts/bench_calibration.py's.
- `solved_again`: that run's captures (a copy of its folder) calibrated again offline with the
  robot's own errors estimated (`--robot-offsets`): the result is the copy's results-2.
- `small`: 10 stations at half resolution (640x480), the reference of the tests about how a run
  is driven (a hardware driver, the controller emulator, resume): a run driven another way must
  give what this simulated run gave. Too few pixels for accuracy (3.7 mm from the truth, where
  the nominal mount is 3 mm off): never test accuracy on it. Ten stations, not fewer: one of
  their moves is refused by the planner's validation (a sample beyond a joint limit) and planned
  again, the only such case in these tests.

READ them only: a test that writes into a run works on a copy (`shutil.copytree`).
"""

from __future__ import annotations

import pickle
import shutil
from dataclasses import replace
from pathlib import Path

from scanner.calibrate.config import CalibrateConfig
from scanner.calibrate.eye_in_hand import run_eye_in_hand
from scanner.calibrate.offline import OfflineOptions, calibrate_directory
from scanner.calibrate.solve import CalibrationRun
from tests.conftest import built_once
from tests.tiny_scan import HALF_RESOLUTION

_RUN = "run.pickle"


def with_stations(config: CalibrateConfig, count: int) -> CalibrateConfig:
    return replace(config, stations=replace(config.stations, count=count))


EIGHT_STATIONS = with_stations(CalibrateConfig(), 8)
SMALL = replace(with_stations(CalibrateConfig(), 10), camera=HALF_RESOLUTION)


def _built(run_dir: Path, name: str, make) -> CalibrationRun:
    """The CalibrationRun `make(folder)` returned, built once into run_dir/name and kept there."""

    def build(out: Path) -> None:
        out.mkdir(parents=True)
        run = make(out)
        (out / _RUN).write_bytes(pickle.dumps(run))

    return pickle.loads((built_once(run_dir, name, build) / _RUN).read_bytes())


def eight_stations(run_dir: Path) -> CalibrationRun:
    return _built(
        run_dir, "calibration-8", lambda out: run_eye_in_hand(EIGHT_STATIONS, out / "cal")
    )


def solved_again(run_dir: Path) -> CalibrationRun:
    """`scanner calibrate --offline` with `--robot-offsets` on a copy of `eight_stations`' run
    folder (its results/ kept; the new results in results-2)."""

    def make(out: Path) -> CalibrationRun:
        copy = out / "cal"
        shutil.copytree(eight_stations(run_dir).out_dir, copy)
        solver = replace(EIGHT_STATIONS.solver, robot_offsets=True)
        return calibrate_directory(copy, OfflineOptions(), solver)

    return _built(run_dir, "calibration-8-again", make)


def small(run_dir: Path) -> CalibrationRun:
    return _built(run_dir, "calibration-small", lambda out: run_eye_in_hand(SMALL, out / "cal"))
