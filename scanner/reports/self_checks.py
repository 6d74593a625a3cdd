"""Did a result pass its own checks? One place decides, for scan, reconstruct, merge and batches.

A result that fails a self-check is still written (nothing computed is thrown away, and the
summary says what went wrong), but the command exits with `EXIT_SELF_CHECK_FAILED` and prints
the verdict as its last line: a script, a batch or a cell controller that reads only the exit
code must not take a distorted model for a good one.

The checks are those judged without truth, so that they mean the same on a real cell:
- the hand-eye correction converged (`reconstruction.handeye.diagnosis`);
- every hanging's alignment verified (a merge refuses an unverified one outright, exit 3; a
  scan's reconstruction leaves the hanging out of its model, writes the model of the others
  and fails here, as does any result that records an unverified one).
"""

from __future__ import annotations

EXIT_SELF_CHECK_FAILED = 6


def self_check_failures(report: dict) -> list[str]:
    """The failed self-checks of a result's report, each as a short clause (empty: passed)."""
    failures = []
    if not report.get("handeye_converged", True):
        why = "; ".join(report.get("handeye_diagnosis", {}).get("failures", []))
        failures.append("the hand-eye correction did not converge" + (f" ({why})" if why else ""))
    for p in report.get("hangings", []):
        if p.get("left_out"):
            why = "; ".join(p.get("failures", []))
            failures.append(
                f"hanging {p['hanging']} did not align with the hangings before it"
                + (f" ({why})" if why else "")
                + " and is left out of the model (scanner scan --resume scans it again)"
            )
        elif p.get("verified") is False:
            failures.append(f"hanging {p['hanging']}'s alignment did not verify")
    return failures


def self_check_record(report: dict) -> dict:
    """The `self_checks` entry of report.json: passed, the failures and the exit code."""
    failures = self_check_failures(report)
    return {
        "passed": not failures,
        "failures": failures,
        "exit_code": EXIT_SELF_CHECK_FAILED if failures else 0,
    }


def exit_code(report: dict) -> int:
    return self_check_record(report)["exit_code"]


def verdict_line(report: dict) -> str:
    """The last line a command prints about one result."""
    failures = self_check_failures(report)
    if not failures:
        return "verdict: the result passed its self-checks"
    return (
        f"verdict: FAILED its self-checks: {'; '.join(failures)}; the files are written but "
        f"should not be trusted (exit code {EXIT_SELF_CHECK_FAILED})"
    )
