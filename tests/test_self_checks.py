"""A result that fails its own checks is written but exits non-zero, with the verdict last."""

import json

import pytest

from scanner.commands.main import main
from scanner.reports.self_checks import (
    EXIT_SELF_CHECK_FAILED,
    exit_code,
    self_check_failures,
    self_check_record,
    verdict_line,
)


def _report(converged: bool, verified=(True,)) -> dict:
    return {
        "handeye_converged": converged,
        "handeye_diagnosis": {
            "failures": [] if converged else ["match RMS 3.10 mm (limit 0.8 mm)"]
        },
        "hangings": [{"hanging": 1}]
        + [{"hanging": k + 2, "verified": v} for k, v in enumerate(verified)],
    }


def test_a_converged_result_passes_and_exits_zero():
    r = _report(True)
    assert self_check_failures(r) == [] and exit_code(r) == 0
    assert self_check_record(r) == {"passed": True, "failures": [], "exit_code": 0}
    assert verdict_line(r).startswith("verdict: the result passed")


def test_a_result_without_a_correction_passes():
    assert exit_code({}) == 0


def test_hand_eye_not_converged_fails_with_its_reason():
    r = _report(False)
    failures = self_check_failures(r)
    assert len(failures) == 1 and "did not converge (match RMS 3.10 mm" in failures[0]
    assert exit_code(r) == EXIT_SELF_CHECK_FAILED != 0
    line = verdict_line(r)
    assert line.startswith("verdict: FAILED") and f"exit code {EXIT_SELF_CHECK_FAILED}" in line


def test_an_unverified_hanging_fails():
    r = _report(True, verified=(True, False))
    assert self_check_failures(r) == ["hanging 3's alignment did not verify"]
    assert self_check_record(r)["exit_code"] == EXIT_SELF_CHECK_FAILED


@pytest.fixture(scope="module")
def failed_result(tiny_scan, tmp_path_factory):
    """The tiny scan reconstructed with its hand-eye correction on: five views cannot pin the
    mount down, and the diagnosis says so."""
    out = tmp_path_factory.mktemp("failed") / "results"
    config = tmp_path_factory.mktemp("cfg") / "handeye.yaml"
    config.write_text(
        "reconstruction:\n  handeye:\n    enabled: true\n"
        "  surfaces:\n    poisson_depth: 6\n    tsdf_voxel_size_m: 0.002\n"
        "    fused_voxel_size_m: 0.002\nmetric_samples: 20000\n"
    )
    return out, config


def test_reconstruct_of_a_non_converged_correction_exits_with_the_verdict_last(
    tiny_scan, failed_result, capsys
):
    out, config = failed_result
    rc = main(["reconstruct", str(tiny_scan.scan_dir), "--config", str(config), "--out", str(out)])
    printed = capsys.readouterr().out.strip().splitlines()
    report = json.loads((out / "report.json").read_text())
    assert report["handeye_converged"] is False, "the five-view correction is expected to fail"
    # Everything is written as before; the exit code and the last line say it is not to be trusted.
    assert (out / "summary.md").is_file() and (out / "mesh_poisson.ply").is_file()
    assert rc == EXIT_SELF_CHECK_FAILED
    assert printed[-1].startswith("verdict: FAILED its self-checks: the hand-eye correction")
    assert report["self_checks"]["exit_code"] == EXIT_SELF_CHECK_FAILED
    assert report["self_checks"]["passed"] is False


def test_the_tiny_scans_own_result_passes(tiny_scan):
    assert tiny_scan.report["self_checks"] == {"passed": True, "failures": [], "exit_code": 0}
