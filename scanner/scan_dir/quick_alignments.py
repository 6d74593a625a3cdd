"""The pass alignments the quick model of `hangings: auto` found while the scan ran, kept in the
manifest (`quick_alignments`, by 0-based pass) so that the reconstruction refines and verifies
them instead of searching all hypotheses a second time (the search is most of the alignment's
time, and it ran after the pass's last picture, where the user waits).

Only verified alignments are kept. A pass scanned again takes its own, and those of the passes
after it (aligned onto it), with it: they were found on captures that are now set aside.
"""

from __future__ import annotations

import numpy as np

from reconstruction.common.errors import ScannerError
from reconstruction.common.transforms import check_pose
from reconstruction.hangings.alignment import PassAlignment
from scanner.scan_dir.captures import CaptureStore
from scanner.scan_dir.manifest import SavedScan

KEY = "quick_alignments"


def record_quick_alignments(store: CaptureStore, alignments: list[PassAlignment]) -> None:
    """Keep the verified ones of `alignments` in the manifest (replacing a pass's earlier)."""
    verified = {
        str(a.hanging): {
            "T": [[float(x) for x in row] for row in np.asarray(a.T)],
            "ambiguity": float(a.ambiguity),
            "hypotheses": int(a.hypotheses),
        }
        for a in alignments
        if a.verified
    }
    if verified:
        kept = store.read_manifest().get(KEY) or {}
        store.update_manifest(**{KEY: {**kept, **verified}})


def quick_alignments(scan: SavedScan) -> dict[int, PassAlignment]:
    """The kept alignments by 0-based pass (the manifest read now); figures the reconstruction
    measures again are NaN."""
    out, nan = {}, float("nan")
    for key, record in (scan.store.read_manifest().get(KEY) or {}).items():
        field = f"{scan.store.manifest_path}: {KEY}: {key}"
        try:
            h, T = int(key), np.array(record["T"], float)
            ambiguity, hypotheses = float(record["ambiguity"]), int(record["hypotheses"])
        except (TypeError, ValueError, KeyError) as e:
            raise ScannerError(
                f"{field}: expected T (4x4), ambiguity and hypotheses ({e})"
            ) from None
        T = check_pose(T, f"{field}: T")
        out[h] = PassAlignment(h, T, nan, nan, nan, nan, ambiguity, hypotheses, ())
    return out


def without_passes_from(manifest: dict, hanging: int) -> dict | None:
    """The manifest's kept alignments less those of pass `hanging` (0-based) and after (None
    when none is left)."""
    kept = {k: v for k, v in (manifest.get(KEY) or {}).items() if int(k) < hanging}
    return kept or None
