"""The clocks of the reports and benchmarks: wall time per stage, CPU time of a run."""

import time

from reconstruction.common.stage_timer import StageTimer, cpu_seconds


def _busy(cpu_s: float) -> None:
    """Compute until this process has used cpu_s more CPU seconds (by Python's own clock)."""
    end = time.process_time() + cpu_s
    while time.process_time() < end:
        pass


def test_stages_sum_their_wall_time():
    timer = StageTimer()
    for _ in range(2):
        with timer("wait"):
            time.sleep(0.1)
    assert 0.19 < timer.seconds["wait"] < 1.0


def test_cpu_seconds_count_work_not_waiting():
    start = cpu_seconds()
    time.sleep(0.3)
    slept = cpu_seconds() - start
    start = cpu_seconds()
    _busy(0.3)
    busy = cpu_seconds() - start
    assert slept < 0.1
    assert 0.25 < busy < 1.0
