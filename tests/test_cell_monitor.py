"""The cell monitor in a scan: an intruder stops the arm and holds the captures until the cell
is clear, every view is still captured, a failing monitor stops the arm, bad input is refused.
Ground truth: the simulated intruder's path."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from reconstruction.common.errors import ScannerError
from scanner.commands.main import main
from scanner.configs.scan import ScanConfig, with_overrides
from scanner.configs.typed_yaml import from_dict
from scanner.monitor.cell_monitor import MonitorStoppedError
from scanner.scan.run import run_scan
from tests.tiny_scan import TINY_SCAN

pytestmark = pytest.mark.slow


def _config(**flags) -> ScanConfig:
    config = with_overrides(from_dict(ScanConfig, TINY_SCAN, "tiny"), monitor=True, **flags)
    # Tests share the machine with other tests: the lag limit is the product's, times four.
    monitor = replace(config.monitor, max_lag_s=2.0)
    return replace(config, reconstruct=False, monitor=monitor)


@pytest.fixture(scope="module")
def intruded(tmp_path_factory):
    return run_scan(_config(intruder_start_s=(4.0,)), tmp_path_factory.mktemp("mon") / "scan")


def test_an_intruder_pauses_the_scan_and_no_capture_is_taken_while_it_is_there(intruded):
    from robots.simulation.cell_video.intruders import default_intruder_paths

    r = intruded.report
    m = r["monitor"]
    assert r["views_captured"] == r["views_planned"] == 5
    assert m["intrusions"] == 1 and m["detected"] == 1 and m["false_alarms"] == 0
    assert m["detection_latency_ms_max"] <= 200
    assert m["captures"] == 5 and m["captures_during_intrusion"] == 0
    kinds = [e["kind"] for e in m["events"]]
    assert "intrusion" in kinds and "paused" in kinds and "clear" in kinds
    # The cell is declared clear only after the intruder has left the monitored volume.
    (path,) = default_intruder_paths((4.0,), 0)
    # The intruder (its path, known only to the simulator) is in the truth file.
    truth = yaml.safe_load((intruded.scan_dir / "truth.yaml").read_text())
    (recorded,) = truth["intruders"]
    assert recorded["start_s"] == 4.0 and recorded["stop_m"] == pytest.approx(list(path.stop_m))
    clear = next(e["t_s"] for e in m["events"] if e["kind"] == "clear")
    assert not path.present(clear) and clear > path.start_s
    # The tool is tracked while the arm moves.
    assert m["ee_tracked_frames"] >= 10 and m["ee_tracking_rms_mm"] < 5.0


def test_the_arm_still_reaches_every_view_after_an_interrupted_motion(intruded, tmp_path):
    from scanner.scan_dir.captures import CaptureStore

    # The same scan without the monitor: the pause changes the path, never the goals.
    plain = run_scan(replace(_config(), monitor=ScanConfig().monitor), tmp_path / "plain")
    watched, unwatched = CaptureStore.open(intruded.scan_dir), CaptureStore.open(plain.scan_dir)
    assert watched.captured_indices() == unwatched.captured_indices()
    for i in watched.captured_indices():
        q_a, q_b = watched.read_capture(i).q_rad, unwatched.read_capture(i).q_rad
        assert np.allclose(q_a, q_b, atol=1e-9), i
    assert intruded.report["monitor"]["pauses"] >= 1


def test_a_failing_monitor_stops_the_arm_before_it_moves(tmp_path, monkeypatch):
    import scanner.monitor.detector as detector

    def broken(self, *args, **kwargs):
        raise RuntimeError("camera unplugged")

    calls = {"n": 0}
    original = detector.IntrusionDetector.update

    def fails_after_warm_up(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > self.config.warmup_frames + 1:
            return broken(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(detector.IntrusionDetector, "update", fails_after_warm_up)
    with pytest.raises(MonitorStoppedError, match="camera unplugged.*robot was stopped"):
        run_scan(_config(), tmp_path / "scan")
    from scanner.scan_dir.captures import CaptureStore

    store = CaptureStore.open(tmp_path / "scan")
    assert store.captured_indices() == [] and store.read_manifest()["status"] == "interrupted"


def test_a_monitor_that_falls_behind_stops_the_arm(tmp_path, monkeypatch):
    import time

    import scanner.monitor.detector as detector

    original = detector.IntrusionDetector.update

    def slow_after_warm_up(self, *args, **kwargs):
        if self.ready:
            time.sleep(0.1)  # 100 ms per frame against a camera's 67 ms at 15 fps
        return original(self, *args, **kwargs)

    monkeypatch.setattr(detector.IntrusionDetector, "update", slow_after_warm_up)
    config = _config()
    config = replace(config, monitor=replace(config.monitor, max_lag_s=0.3))
    with pytest.raises(MonitorStoppedError, match="fell .* behind the camera"):
        run_scan(config, tmp_path / "scan")
    from scanner.scan_dir.captures import CaptureStore

    assert CaptureStore.open(tmp_path / "scan").read_manifest()["status"] == "interrupted"


def test_a_frame_rate_the_machine_cannot_keep_up_with_is_refused(tmp_path):
    config = _config()
    detection = replace(config.monitor.detection, fps=900.0)
    config = replace(config, monitor=replace(config.monitor, detection=detection))
    with pytest.raises(ScannerError, match="monitor.detection.fps: the monitor processes"):
        run_scan(config, tmp_path / "scan")


def test_bad_monitor_input_is_a_one_line_error(tmp_path, capsys):
    cases = [
        (["scan", "--intruder", "4"], "--intruder: simulated intruders need the monitor on"),
        (["scan", "--monitor", "--intruder", "-1"], "expected times >= 0 s"),
        (["scan", "--monitor", "--intruder", "4,x"], "expected seconds"),
        (["monitor", "--duration", "5", "--intruder", "6"], "not within --duration"),
    ]
    for argv, needle in cases:
        try:
            code = main([*argv, "--out", str(tmp_path / "x")] if argv[0] == "scan" else argv)
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        assert code == 2 and needle in err and err.count("\n") == 1, (argv, err)
    with pytest.raises(ScannerError, match="--intruder: 500 s is after the end of the scan"):
        run_scan(_config(intruder_start_s=(500.0,)), tmp_path / "late")


def test_the_monitor_command_reports_an_intruder(tmp_path, capsys):
    # The intruder reaches in as the background model is ready (2 s of frames) and is seen
    # at once (measured: 2.13 s); the lag limit as in _config.
    config = tmp_path / "monitor.yaml"
    config.write_text(yaml.safe_dump({"monitor": {"max_lag_s": 2.0}}))
    assert main(["monitor", "--duration", "3", "--intruder", "2", "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert "intrusions 1 of 1 detected, 0 false alarms" in out
    assert "monitor: 45 frames over 3.0 s" in out
