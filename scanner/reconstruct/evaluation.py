"""The reconstruction against the simulator's truth (when truth.yaml is there): surface metrics,
observed fraction, hand-eye error, and per hanging its coverage and alignment error, all in the
first (scan's first) hanging's frame."""

from __future__ import annotations

import math

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import invert, transform_points
from reconstruction.evaluation.metrics import (
    TriangleSurface,
    evaluate_surface,
    handeye_error,
    sample_surface,
    truth_sampling,
    visible_mask,
)
from reconstruction.evaluation.observable import observable_mask, working_distance_m
from reconstruction.evaluation.support import SupportPlane
from reconstruction.hangings.alignment import alignment_error
from reconstruction.pipeline import ReconstructionResult
from reconstruction.surfaces.fixture import points_on_fixture
from scanner.configs.scan import ProcessingConfig
from scanner.reconstruct.scan_views import Gathered


def _true_eyes(
    views: Gathered, to_first: list[np.ndarray], left_out: tuple[int, ...] = ()
) -> dict[int, np.ndarray]:
    """True left and right camera centres (2, 3) of every view (by capture index), in the first
    hanging's frame (`to_first`: per hanging, the true transform of its placement onto the
    first's); none of the hangings `left_out` of the model."""
    from robots.arms.default import arm_of
    from robots.models.kinematics import Kinematics

    hanging_of = {i: h for h, indices in enumerate(views.hangings) for i in indices}
    kinematics = {robot: Kinematics(arm_of(robot)) for robot in set(views.robots)}
    eyes = {}
    for i, q in views.joints.items():
        if hanging_of[i] in left_out:
            continue
        truth = views.truths[views.scan_of[i]][0]
        kin = kinematics[views.robots[views.scan_of[i]]]
        X_WC = kin.X_WF(q + truth.joint_offsets_rad) @ truth.X_FC
        eyes[i] = transform_points(
            to_first[hanging_of[i]], (truth.rgbd or truth.stereo).eye_centres_W(X_WC)
        )
    return eyes


def _true_supports(
    views: Gathered, to_first: list[np.ndarray], indices
) -> list[SupportPlane | None] | None:
    """Per view (capture indices `indices`), the top of its pass's support in the first
    hanging's frame; None when no pass stood on one."""
    if not any(s is not None for s in views.supports):
        return None
    hanging_of = {i: h for h, group in enumerate(views.hangings) for i in group}
    out = []
    for i in indices:
        support = views.supports[hanging_of[i]]
        out.append(None if support is None else support.moved(to_first[hanging_of[i]]))
    return out


def _object_poses(truth) -> list[np.ndarray]:
    """The object's true pose in each hanging of one scan."""
    raw = truth[2]
    return [np.array(X, float) for X in raw.get("X_WO_hangings", [truth[0].X_WO])]


def to_first_hanging(views: Gathered) -> list[np.ndarray] | None:
    """Per hanging (over all scans), the true transform of its placement onto the first
    scan's first hanging; None without truth for every scan."""
    if any(t is None for t in views.truths):
        return None
    poses = [X for t in views.truths for X in _object_poses(t)]
    if len(poses) != len(views.hangings):
        return None
    return [poses[0] @ invert(X) for X in poses]


def _pass_observed(surface, eyes: list[np.ndarray], supports=None) -> float:
    """The share of the true surface one hanging's (true) views saw (`supports`: per view, the
    top its object stood on, which hides what lies on it)."""
    samples = sample_surface(surface, 50_000)
    return float(visible_mask(samples, surface, eyes, supports=supports).mean())


def hangings_report(result, views: Gathered, to_first) -> dict:
    """Per hanging its views, coverage and alignment figures (a hanging left out of the model:
    `left_out` and the checks it failed), and (with truth) its observed fraction and
    alignment errors (a left-out hanging's: of its best, unverified fit)."""
    surface = views.truths[0][1] if to_first is not None else None
    true_eyes = _true_eyes(views, to_first) if to_first is not None else {}
    usable = {v.index for v in views.views}
    passes = []
    for h in range(len(views.hangings)):
        if h in result.left_out:  # its views are in no pose of the result
            indices = [i for i in views.hangings[h] if i in usable]
        else:
            indices = [v.index for v in result.views if v.hanging == h]
        record: dict = {
            "hanging": h + 1,
            "views": len(indices),
            "coverage_estimate": result.hanging_coverage[h].fraction,
        }
        if surface is not None:
            record["observed_fraction"] = _pass_observed(
                surface,
                [true_eyes[i] for i in indices],
                _true_supports(views, to_first, indices),
            )
        a = next((a for a in result.alignments if a.hanging == h), None)
        if a is not None:
            record.update(
                overlap=a.overlap,
                inlier_rms_mm=1e3 * a.inlier_rms_m,
                free_space_violation=a.free_space_violation,
                colour_agreement=a.colour_agreement,
                ambiguity=a.ambiguity,
                verified=a.verified,
            )
            if a.from_known_turn:  # a turntable's turn, verified without the search
                record["known_turn_verified"] = True
            if a.from_earlier:  # the scan's quick alignment, refined and verified again
                record["quick_alignment_refined"] = True
            if not a.verified:
                record.update(left_out=True, failures=list(a.failures))
            if surface is not None:
                points_h = transform_points(invert(to_first[h]), surface.vertices)
                dt, dr = alignment_error(a.T, to_first[h], points_h)
                record.update(alignment_error_mm=1e3 * dt, alignment_error_deg=math.degrees(dr))
        passes.append(record)
    out: dict = {"hangings": passes}
    errors = [p for p in passes if "alignment_error_mm" in p and not p.get("left_out")]
    if errors:
        out["alignment_error_mm"] = max(p["alignment_error_mm"] for p in errors)
        out["alignment_error_deg"] = max(p["alignment_error_deg"] for p in errors)
    return out


def evaluate(
    result: ReconstructionResult,
    truth,
    surface,
    samples: int,
    truth_samples,
    fixtures=(),
    observable=None,
) -> dict:
    """Metrics of every surface against the truth (`truth_samples`: from `observed_samples`;
    `observable`: which of them a camera could see at all, from `observable_samples`), the
    points on the fixture in each (`fixtures`: every hanging's rod line in the first hanging's
    frame), and the hand-eye error before/after."""
    out: dict = {"surfaces": {}}
    results = {name: TriangleSurface(m.vertices, m.triangles) for name, m in result.meshes.items()}
    given = {"n_samples": samples, "truth_samples": truth_samples, "observable": observable}
    for name, mesh in results.items():
        out["surfaces"][name] = evaluate_surface(None, surface, result_mesh=mesh, **given)
    out["surfaces"]["fused_cloud"] = evaluate_surface(result.fused.points_W, surface, **given)
    points = {name: m.vertices for name, m in result.meshes.items()}
    for name, p in {**points, "fused_cloud": result.fused.points_W}.items():
        on = sum(points_on_fixture(p, surface.vertices, line) for line in fixtures)
        out["surfaces"][name]["fixture_points"] = on
    before = handeye_error(result.X_FC_nominal, truth.X_FC)
    after = handeye_error(result.X_FC, truth.X_FC)
    out.update(after)
    out["handeye_error_before_mm"] = before["handeye_error_mm"]
    out["handeye_error_before_deg"] = before["handeye_error_deg"]
    return out


def observed_samples(views: Gathered, processing: ProcessingConfig, to_first, left_out=()):
    """Samples of the first scan's true surface and which of them the true views saw (not
    those of the hangings `left_out` of the model)."""
    true_eyes = _true_eyes(views, to_first, left_out)
    supports = _true_supports(views, to_first, list(true_eyes))
    return truth_sampling(
        views.truths[0][1], list(true_eyes.values()), processing.metric_samples, supports=supports
    )


def observable_samples(views: Gathered, to_first, truth_samples, left_out=()) -> np.ndarray | None:
    """Which of `truth_samples`' samples a camera at the scan's working distance could see from
    some direction around the object (None without true views)."""
    eyes = list(_true_eyes(views, to_first, left_out).values())
    if not eyes:
        return None
    surface = views.truths[0][1]
    return observable_mask(truth_samples[0], surface, working_distance_m(surface, eyes))


def truth_metrics(
    result, views: Gathered, processing: ProcessingConfig, to_first, truth_samples=None
) -> dict:
    """The report's accuracy keys (against the first scan's truth, in its first hanging's
    frame): the primary surface's metrics first, then all of them. `truth_samples`: from
    `observed_samples`, when already computed."""
    truth = views.truths[0]
    if truth_samples is None:
        truth_samples = observed_samples(views, processing, to_first, result.left_out)
    fixtures = [
        line.moved(T)
        for h, (line, T) in enumerate(zip(views.fixtures, to_first or [], strict=False))
        if h not in result.left_out
    ]
    observable = observable_samples(views, to_first, truth_samples, result.left_out)
    metrics = evaluate(
        result, truth[0], truth[1], processing.metric_samples, truth_samples, fixtures, observable
    )
    primary = metrics["surfaces"].get(processing.primary_surface)
    if primary is None:
        raise ScannerError(
            f"processing.primary_surface: '{processing.primary_surface}' was not built "
            f"(built: {', '.join(metrics['surfaces'])})"
        )
    return {**primary, "primary_surface": processing.primary_surface, **metrics}
