"""`scanner inspect`'s parser and runner (the work: scanner/inspect.py)."""

from __future__ import annotations

import argparse

from scanner.commands.arguments import (
    LENGTH_HELP,
    LengthOption,
    add_command,
    add_output_arguments,
    path_arg,
    typed_text,
)

# Exit code of an inspection that ran but found the part out of tolerance.
EXIT_OUT_OF_TOLERANCE = 4


def share_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share such as 0.95, got '{text}'") from None
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a share in (0, 1], got {text}")
    return v


def add_inspect_parser(sub) -> None:
    from scanner.inspect.inspection import InspectOptions

    defaults = InspectOptions(reference=None)
    inspect = add_command(
        sub,
        "inspect",
        "scanner.commands.inspect:run_inspect_command",
        help="compare a model with its reference (CAD) mesh: deviations, picture, pass/fail",
        description="Align a reference mesh (e.g. the part's CAD model) onto a reconstructed "
        "model (global features + ICP, reported), then give the signed deviation of every "
        "model vertex from it (mean, RMS, p90, max, share within --tolerance), a picture of "
        "the model coloured by deviation, and a pass/fail line. Exit code 0 pass, "
        f"{EXIT_OUT_OF_TOLERANCE} out of tolerance, 3 when the reference cannot be aligned.",
    )
    inspect.add_argument(
        "model",
        type=path_arg,
        metavar="MESH_OR_SCAN",
        help="a mesh file, a scan directory (its results/), or a results folder",
    )
    inspect.add_argument(
        "--reference",
        type=path_arg,
        required=True,
        help="the reference mesh (.ply/.obj/.stl) in any frame (required; no default)",
    )
    inspect.add_argument(
        "--tolerance",
        action=LengthOption,
        default=defaults.tolerance_m,
        help=f"deviation allowed either side of the reference; {LENGTH_HELP}; less than the "
        f"model's size (default {defaults.tolerance_m:g} m = {1e3 * defaults.tolerance_m:g} mm)",
    )
    inspect.add_argument(
        "--min-within",
        type=share_arg,
        default=defaults.min_within,
        metavar="SHARE",
        help="share of the model's vertices that must be within tolerance to pass "
        "(default %(default)s)",
    )
    inspect.add_argument(
        "--scale",
        action=LengthOption,
        default=defaults.scale_m,
        help=f"end of the picture's colour scale, +-; {LENGTH_HELP} (default "
        f"{defaults.scale_m:g} m = {1e3 * defaults.scale_m:g} mm)",
    )
    inspect.add_argument(
        "--reference-unit",
        choices=("auto", "m", "mm"),
        default=defaults.reference_unit,
        help="unit of the reference file's numbers; auto picks the one under which its size "
        "is nearest the model's (default %(default)s)",
    )
    inspect.add_argument(
        "--align",
        choices=("best-fit", "none"),
        default=defaults.align,
        help="best-fit: align the reference onto the model (features + ICP); none: take it "
        "where it is, e.g. placed by a fixture (default %(default)s)",
    )
    add_output_arguments(
        inspect,
        "folder to write the inspection into (default: inspection[-N] beside the mesh, or in "
        "the results folder)",
        "replace an inspection already in --out",
    )


def run_inspect_command(args: argparse.Namespace) -> int:
    from scanner.inspect.inspection import InspectOptions, run_inspect, verdict_line

    options = InspectOptions(
        args.reference,
        args.tolerance,
        args.scale,
        args.min_within,
        args.reference_unit,
        args.align,
        args.out,
        args.force,
        {name: typed_text(args, name) for name in ("tolerance", "scale")},
    )
    run = run_inspect(args.model, options)
    r = run.report
    a, d = r["alignment"], r["deviation"]
    print(
        f"alignment ({a['start']}, reference read in {r['reference_unit']}): "
        f"{100 * a['overlap']:.1f} % of the model on the reference, inlier RMS "
        f"{a['inlier_rms_mm']:.3f} mm"
    )
    print(
        f"deviation: mean {d['mean_mm']:.3f} mm, RMS {d['rms_mm']:.3f} mm, p90 |d| "
        f"{d['p90_abs_mm']:.3f} mm, max |d| {d['max_abs_mm']:.3f} mm"
    )
    print(verdict_line(r))
    print(f"inspection: {run.out} (summary.md, {', '.join(r['files'])})")
    return 0 if run.passed else EXIT_OUT_OF_TOLERANCE
