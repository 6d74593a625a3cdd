"""results/summary.md: what a reconstruction produced and whether it is good (every figure
defined, with its band: scanner.reports.judgement), the options behind it, and the hand-eye story.

Units follow scanner.reports.units: accuracy figures in mm and degrees, everything else SI.
"""

from __future__ import annotations

from pathlib import Path

from scanner.reports.judgement import FIGURES, TABLE_HEAD, TRUTH_FIGURES, figure_row


def _fmt(value, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _hangings_lines(report: dict) -> list[str]:
    passes = report.get("hangings")
    if not passes or len(passes) < 2:
        return []
    lines = [
        "",
        "## Hangings (each further one aligned onto those before it)",
        "",
        "| hanging | views | overlap | inlier RMS mm | seen-through | verified | error mm, deg |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in passes:
        error = (
            f"{_fmt(p['alignment_error_mm'])} / {_fmt(p['alignment_error_deg'])}"
            if "alignment_error_mm" in p
            else "-"
        )
        lines.append(
            f"| {p['hanging']} | {p['views']} | {_fmt(p.get('overlap', '-'))} | "
            f"{_fmt(p.get('inlier_rms_mm', '-'))} | {_fmt(p.get('free_space_violation', '-'))} | "
            f"{'left out' if p.get('left_out') else p.get('verified', 'reference')} | {error} |"
        )
    return lines


def left_out_warning(report: dict) -> str | None:
    """The warning for hangings left out of the model (None when every hanging is in it)."""
    left = [p for p in report.get("hangings", []) if p.get("left_out")]
    if not left:
        return None
    words = "; ".join(
        f"hanging {p['hanging']} ({'; '.join(p.get('failures', [])) or 'not verified'})"
        for p in left
    )
    return (
        f"WARNING: left out of the model, not aligned with the hangings before them: {words}. "
        "The model is that of the other hangings; the captures are kept. "
        "`scanner scan --resume SCAN_DIR` scans the first of them again (its captures and "
        "these results are moved aside to SCAN_DIR/set_aside/, not deleted)."
    )


def _decision_lines(report: dict) -> list[str]:
    """With `hangings: auto`: per hanging the coverage the scanner estimated before and after
    it, why another was asked for and the instruction given, and why it stopped."""
    decisions = report.get("hanging_decisions")
    if not decisions:
        return []
    lines = [
        "",
        "## Hangings asked for (hangings: auto)",
        "",
        "| hanging | coverage before | coverage after | next hanging asked because | instruction |",
        "|---|---|---|---|---|",
    ]
    for d in decisions:
        nxt = d.get("next", {})
        words = nxt.get("words", "-")
        if "picture" in nxt:
            words += f" ([picture](../{nxt['picture']}))"
        lines.append(
            f"| {d['hanging']} | {_fmt(d['coverage_before'])} | {_fmt(d['coverage_after'])} | "
            f"{nxt.get('asked_because', '-')} | {words} |"
        )
    if report.get("stop_reason"):
        lines += ["", f"Stopped asking for hangings: {report['stop_reason']}."]
    return lines


def _presentation_lines(report: dict) -> list[str]:
    """On a turntable: each pass's angle, the turn before it and why it was made; whether the
    known turns verified without the search, and the axis they calibrated. On the table: the
    face each pass lay on and why it was asked for."""
    presented = report.get("presentation")
    if not presented:
        return []
    if presented["kind"] == "table":
        lines = ["", "## Presentation: table", "", "| pass | laid on | why |", "|---|---|---|"]
        for p in presented["passes"]:
            lines.append(f"| {p['pass']} | {p['laid_on']} | {p.get('why', '-')} |")
        return lines
    lines = [
        "",
        f"## Presentation: {presented['kind']}",
        "",
        "| pass | angle deg | turned deg | why |",
        "|---|---|---|---|",
    ]
    for p in presented["passes"]:
        turned = _fmt(p["turn_deg"], 1) if "turn_deg" in p else "-"
        lines.append(
            f"| {p['pass']} | {_fmt(p['angle_deg'], 1)} | {turned} | {p.get('why', '-')} |"
        )
    turntable = report.get("turntable")
    if turntable:
        known = turntable["known_turn_verified"]
        lines += [
            "",
            f"Known turns verified without the search for hypotheses: {sum(known)} of "
            f"{len(known)}. Turntable axis "
            + (
                f"calibrated from the verified turns: {_fmt(turntable['axis_offset_mm'], 2)} mm "
                f"and {_fmt(turntable['axis_tilt_deg'], 3)} deg off the cell model's"
                + (
                    f" ({_fmt(turntable['axis_error_mm'], 2)} mm and "
                    f"{_fmt(turntable['axis_error_deg'], 3)} deg off the simulator's true axis)."
                    if "axis_error_mm" in turntable
                    else "."
                )
                if turntable["axis_calibrated"]
                else "not calibrated (no verified turn): the cell model's."
            ),
        ]
    return lines


def handeye_warning(report: dict) -> str | None:
    """The warning for a hand-eye correction that did not converge (None when it did or did
    not run)."""
    if report.get("handeye_converged", True):
        return None
    failures = "; ".join(report.get("handeye_diagnosis", {}).get("failures", []))
    return (
        f"WARNING: the hand-eye correction did not converge ({failures}); the model may be "
        "distorted. Calibrate the camera mount (`scanner calibrate`) and reconstruct with "
        "--calibration; the cloud at the nominal hand-eye transform is kept as "
        "fused_cloud_nominal.ply."
    )


def _run_lines(report: dict) -> list[str]:
    """What was done: the scan's capture figures (when this folder holds the scan's own
    result), the reconstruction's time and the options behind it."""
    lines = []
    if "views_planned" in report:
        lines += [
            f"- views captured: {report.get('views_captured')} of {report['views_planned']}"
            f" ({report.get('views_skipped', 0)} skipped); robot motion "
            f"{_fmt(report.get('robot_motion_s', 0.0), 1)} s, scan wall time "
            f"{_fmt(report.get('wall_s', 0.0), 1)} s",
        ]
        if report.get("reachable_fraction") is not None:
            lines.append(
                f"- the arm reaches {_fmt(100 * report['reachable_fraction'], 0)} % of the view "
                "sphere (the views' directions with a collision-free IK solution)"
            )
    if "reconstruct_s" in report:
        lines.append(
            f"- reconstruction: {report.get('captures_used')} captures used, "
            f"{len(report.get('captures_skipped', []))} skipped, "
            f"{_fmt(report['reconstruct_s'], 1)} s"
        )
    if "sensor" in report:
        lines.append(f"- sensor: {report['sensor']}")
    s = report.get("settings")
    if s:
        lines.append(
            f"- options: ICP registration {'on' if s['icp'] else 'off (--no-icp)'}, hand-eye "
            f"correction {'on' if s['handeye_correction'] else 'off (--no-handeye)'}, "
            f"surfaces {', '.join(s['surfaces'])} (headline: {s['primary_surface']}), "
            f"mesh files {', '.join(s['mesh_formats'])}, processing settings from "
            f"{s['processing_from']}; X_FC given: {s['X_FC_given']}"
        )
    return lines


def _metric_lines(report: dict) -> list[str]:
    keys = [k for k in TRUTH_FIGURES if k in report]
    if not keys:
        return []
    lines = [
        "",
        f"## The {report.get('primary_surface')} mesh against the simulator's true surface",
        "",
        *TABLE_HEAD,
        *(figure_row(k, report[k]) for k in keys),
    ]
    if "observed_fraction" in report:
        lines += [
            "",
            "Observed against whole object: a camera on the arm sees only part of the object "
            "(a hung object shows its underside and sides, not its top). The *observed* "
            "figures judge the sensing on what was seen; the whole-object ones count the "
            f"unseen {_fmt(100 * (1 - report['observed_fraction']), 0)} % as missing, which "
            "is why the whole-object Chamfer is far larger than the accuracy. "
            "A further hanging (`--hangings 2`) shows the rest.",
        ]
    if "observable_fraction" in report and "coverage_estimate" in report:
        hidden = 1 - report["observable_fraction"]
        lines += [
            "",
            f"Observable at all: {_fmt(100 * report['observable_fraction'], 1)} % of the true "
            "surface faces a camera at the scan's distance from some direction all round; the "
            f"other {_fmt(100 * hidden, 1)} % no scan of this object can see, and the closed "
            "model can only bridge it. Against that ceiling the scan saw "
            f"{_fmt(100 * report['observed_fraction'], 1)} % of the surface and its own "
            f"coverage estimate (no truth) reads {_fmt(100 * report['coverage_estimate'], 1)} %.",
        ]
    return lines


def _surface_lines(report: dict) -> list[str]:
    """Every surface built: its observed-surface figures and its deviation picture."""
    surfaces = report.get("surfaces", {})
    deviation = report.get("deviation", {})
    plots = report.get("plots", {})
    if not surfaces and not deviation:
        return []
    s = report.get("settings", {})
    lines = [
        "",
        "## Every surface",
        "",
        "Deviation pictures: each mesh's vertices coloured by their signed distance to the true "
        f"surface on a fixed scale of +-{_fmt(s.get('deviation_scale_mm', 1.0), 2)} mm (blue "
        "inside, red outside), so runs compare by eye; the tolerance band is "
        f"+-{_fmt(s.get('deviation_tolerance_mm', 0.5), 2)} mm.",
        "",
        "| surface | Chamfer observed mm | accuracy p90 mm | deviation RMS mm | within tolerance |",
        "|---|---|---|---|---|",
    ]
    for name in dict.fromkeys([*surfaces, *deviation]):
        m, d = surfaces.get(name, {}), deviation.get(name, {})
        lines.append(
            f"| {name} | {_fmt(m.get('chamfer_observed_mm', '-'))} | "
            f"{_fmt(m.get('accuracy_p90_mm', '-'))} | {_fmt(d.get('rms_mm', '-'))} | "
            f"{_fmt(100 * d['within_tolerance'], 1) + ' %' if d else '-'} |"
        )
    for name in deviation:
        key = f"deviation_{name}"
        if key in plots:
            lines += ["", f"![{name} deviation]({plots[key]})"]
    return lines


def _given_label(report: dict) -> str:
    return report.get("settings", {}).get("X_FC_given", "the scan's nominal X_FC")


def _handeye_lines(report: dict) -> list[str]:
    """Given, corrected by how much, accepted or not and why; with truth, better or worse."""
    settings = report.get("settings", {})
    if not settings.get("handeye_correction", "handeye_diagnosis" in report):
        return [
            "",
            "## Hand-eye transform X_FC",
            "",
            f"- given: {_given_label(report)}; not "
            "corrected (--no-handeye): the model uses it as given",
        ]
    lines = ["", "## Hand-eye transform X_FC", "", f"- given: {_given_label(report)}"]
    if "X_FC_change_mm" in report:
        lines.append(
            f"- corrected from the scan's own views by {_fmt(report['X_FC_change_mm'])} mm, "
            f"{_fmt(report['X_FC_change_deg'])} deg"
        )
    fit = report.get("handeye_fit")
    if fit:
        lines.append(
            f"- the views' disagreement where they overlap: {_fmt(fit['rms_before_mm'])} mm "
            f"RMS before the correction, {_fmt(fit['rms_after_mm'])} mm after"
        )
    if "handeye_diagnosis" in report:
        d = report["handeye_diagnosis"]
        verdict = "converged" if report["handeye_converged"] else "NOT converged"
        accepted = (
            "accepted: the model is built at the corrected poses"
            if report["handeye_converged"]
            else "not trusted: see the warning at the top"
        )
        lines.append(
            f"- the correction {verdict} (judged without truth): "
            f"{_fmt(100 * d['match_fraction'], 0)} % of the points meet the overlapping views "
            f"(RMS {_fmt(d['match_rms_mm'])} mm), AX = XB on the ICP motions agrees within "
            f"{_fmt(d['axxb_disagreement_mm'])} mm / {_fmt(d['axxb_disagreement_deg'])} deg, "
            f"the last round moved it {_fmt(d['last_change_mm'])} mm; {accepted}"
        )
        if "sigma_mm" in d:
            lines.append(
                f"- the accuracy the correction states (RMS, from how much it depends on each "
                f"view): {_fmt(d['sigma_mm'])} mm, {_fmt(d['sigma_deg'])} deg"
            )
    if "handeye_error_mm" in report:
        before, after = report["handeye_error_before_mm"], report["handeye_error_mm"]
        lines += [
            f"- against the simulator's true mount: given {_fmt(before)} mm, "
            f"{_fmt(report['handeye_error_before_deg'])} deg; estimated {_fmt(after)} mm, "
            f"{_fmt(report['handeye_error_deg'])} deg "
            f"({FIGURES['handeye_error_mm'].verdict(after)}: "
            f"{FIGURES['handeye_error_mm'].band()})",
        ]
        if after > before:
            lines.append(
                "- the correction moved X_FC away from the true mount although the views agree "
                "better: it fits everything that makes the views disagree, the robot's own "
                "pose errors (joint offsets) included, into X_FC. The model is built from the "
                "poses that agree with each other; as an estimate of the mount itself the "
                "given X_FC stays the better one."
            )
    return lines


def write_summary(report: dict, out: Path) -> Path:
    lines = ["# Scan result", ""]
    for warning in (handeye_warning(report), left_out_warning(report)):
        if warning:
            lines += [f"**{warning}**", ""]
    lines += _run_lines(report)
    lines += _metric_lines(report)
    if "coverage_estimate" in report:
        c = report["coverage_estimate"]
        lines += [
            "",
            f"Coverage estimate (no truth): {_fmt(c)} of the closed surface was in some "
            f"camera's view ({FIGURES['coverage_estimate'].verdict(c)}: "
            f"{FIGURES['coverage_estimate'].band()}); about "
            f"{_fmt(1e4 * report['unseen_area_m2'], 1)} cm^2 were not (a further hanging "
            "would show them).",
        ]
    closed = report.get("closed_model")
    if closed:
        lines += [
            "",
            f"Closed model (`mesh_poisson_closed`, for collision models and prints): "
            f"{'watertight' if closed['watertight'] else 'NOT watertight'}; "
            f"{_fmt(1e4 * closed['filled_area_m2'], 1)} cm^2 of it bridge where no data are "
            "(filled, not seen)"
            + (
                f": {_fmt(100 * closed['interpolated_fraction'], 1)} % of its area is "
                "interpolated, not measured."
                if "interpolated_fraction" in closed
                else "."
            ),
        ]
    lines += _surface_lines(report)
    lines += _hangings_lines(report)
    lines += _decision_lines(report)
    lines += _presentation_lines(report)
    lines += _handeye_lines(report)
    if "outputs" in report:
        lines += ["", "## Files", ""] + [f"- `{p}`" for p in report["outputs"].values()]
    if "model_page" in report:
        page = report["model_page"]
        lines += [
            "",
            f"The model in 3D, in any browser (no network needed): [`{page}`]({page}), "
            "or `scanner view` on this folder.",
        ]
    shown = {f"deviation_{n}" for n in report.get("deviation", {})}
    for name, path in report.get("plots", {}).items():
        if name not in shown:
            lines += ["", f"![{name}]({path})"]
    path = out / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path
