"""summary.md says whether the hand-eye correction converged, and warns prominently when not."""

from scanner.reports.summary import handeye_warning, write_summary


def _report(converged: bool) -> dict:
    return {
        "handeye_converged": converged,
        "handeye_diagnosis": {
            "match_fraction": 0.79 if converged else 0.13,
            "match_rms_mm": 0.34 if converged else 2.6,
            "axxb_disagreement_mm": 0.23,
            "axxb_disagreement_deg": 0.026,
            "last_change_mm": 0.11,
            "last_change_deg": 0.02,
            "sigma_mm": 0.21,
            "sigma_deg": 0.031,
            "failures": [] if converged else ["only 13 % of the points meet the overlapping views"],
        },
    }


def test_a_converged_correction_is_stated_without_a_warning(tmp_path):
    text = write_summary(_report(True), tmp_path).read_text()
    assert "the correction converged" in text and "79 % of the points" in text
    assert (
        "the accuracy the correction states (RMS, from how much it depends on each view): "
        "0.210 mm, 0.031 deg" in text
    )
    assert "WARNING" not in text and handeye_warning(_report(True)) is None


def test_a_failed_correction_leads_the_summary_with_a_warning(tmp_path):
    text = write_summary(_report(False), tmp_path).read_text()
    first = text.splitlines()[2]
    assert first.startswith("**WARNING: the hand-eye correction did not converge")
    assert "only 13 % of the points" in first and "scanner calibrate" in first
    assert "fused_cloud_nominal.ply" in first
    assert "NOT converged" in text
