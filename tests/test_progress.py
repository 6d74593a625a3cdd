"""The reconstruction's stage display: names the running stages, reaches 100 %, stays quiet
off a terminal."""

import io

import pytest

from reconstruction.common.stage_timer import StageTimer
from scanner.reconstruct.progress import STAGE_WEIGHTS, StageProgress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _run_stages(display: StageProgress, captures: int) -> None:
    timer = StageTimer(on_stage=display.on_stage)
    with timer("stereo"):
        for _ in range(captures):
            display.on_view()
    for stage in ("filter", "handeye_coarse", "pairs", "icp", "handeye", "icp", "fuse"):
        with timer(stage):
            pass
    with timer("poisson"), timer("tsdf"):
        pass
    for stage in ("coverage", "evaluate", "write"):
        with timer(stage):
            pass


def test_the_bar_names_stages_and_ends_full():
    out = Terminal()
    display = StageProgress(captures=4, file=out)
    seen = []
    original = display.on_stage

    def spy(stage, finished):
        original(stage, finished)
        seen.append(display._bar.desc)

    display.on_stage = spy
    _run_stages(display, 4)
    assert display._bar.n == pytest.approx(sum(STAGE_WEIGHTS.values()))
    display.close()
    assert "reconstruct: stereo" in seen and "reconstruct: poisson, tsdf" in seen
    assert "100%" in out.getvalue()


def test_views_advance_the_stereo_stage_only_once():
    display = StageProgress(captures=4, file=Terminal())
    for _ in range(2):
        display.on_view()
    assert display._bar.n == pytest.approx(STAGE_WEIGHTS["stereo"] / 2)
    display.on_stage("stereo", False)
    display.on_stage("stereo", True)
    assert display._bar.n == pytest.approx(STAGE_WEIGHTS["stereo"])
    display.close()


def test_quiet_off_a_terminal():
    out = io.StringIO()
    display = StageProgress(captures=2, file=out)
    _run_stages(display, 2)
    display.close()
    assert out.getvalue() == ""
