"""A hanging left out of a scan's model (its alignment with the hangings before it did not
verify), and scanning it again.

The scan's reconstruction writes the model of the hangings that aligned and exits with the
self-check failure; the manifest records the hanging left out (`left_out_hangings`, numbered
from 1 as in the report). `scanner scan --resume` of such a scan scans that hanging again:
nothing captured is deleted, its captures and the scan's results are moved aside into
`set_aside/hanging_N/` (with a copy of the truth, whose pose of that hanging the new re-hang
replaces), the operator is asked to hang the object anew, its views are captured again and the
scan is reconstructed. The decisions of `hangings: auto` made after that hanging are made
again from the new captures.

Reopening moves a scan's status back (complete -> running), which `CaptureStore.update_manifest`
refuses by design for everything else; it happens here only, with every file kept.
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.scan_dir.captures import CAPTURES, RESULTS, CaptureStore
from scanner.scan_dir.manifest import SavedScan, open_scan
from scanner.scan_dir.quick_alignments import without_passes_from

log = logging.getLogger("scanner.scan.rescan")

SET_ASIDE = "set_aside"


def left_out_hangings(report: dict) -> list[dict]:
    """The hangings a reconstruction's report left out of the model (numbered from 1), each
    with the checks its alignment failed."""
    return [
        {"hanging": p["hanging"], "failures": list(p.get("failures", []))}
        for p in report.get("hangings", [])
        if p.get("left_out")
    ]


def rescan_advice(scan_dir: Path, left_out: list[dict]) -> str:
    """What the user reads when a hanging was left out: which, why, and how to scan it again."""
    first = left_out[0]
    return (
        f"hanging {first['hanging']} was left out of the model: it did not align with the "
        f"hangings before it ({'; '.join(first['failures'])}); the model of the others is "
        f"written and every capture kept. To scan hanging {first['hanging']} again (its "
        f"captures are moved aside, not deleted): scanner scan --resume {scan_dir}"
    )


def record_left_out(store: CaptureStore, report: dict) -> None:
    """The hangings the model left out, in the manifest (what `--resume` reads), and the
    advice in the log; nothing when every hanging is in the model."""
    left_out = left_out_hangings(report)
    if left_out or "left_out_hangings" in store.read_manifest():
        store.update_manifest(left_out_hangings=left_out or None)
    if left_out:
        log.warning("%s", rescan_advice(store.root, left_out))


def _free_folder(root: Path, hanging: int) -> Path:
    """SCAN_DIR/set_aside/hanging_N, or hanging_N-2, -3, ... for a hanging re-scanned again."""
    base = root / SET_ASIDE / f"hanging_{hanging}"
    candidate, n = base, 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate


def reopen_left_out(saved: SavedScan) -> SavedScan:
    """The scan reopened to capture its first left-out hanging again: that hanging's captures
    and the results moved aside, the re-hang pending, the scan running. Returns it read back."""
    left_out = saved.manifest["left_out_hangings"]
    number = int(left_out[0]["hanging"])  # from 1
    h = number - 1
    if not 0 < h < len(saved.hangings):
        raise ScannerError(
            f"{saved.store.manifest_path}: left_out_hangings names hanging {number}, the scan "
            f"has {len(saved.hangings)}"
        )
    root = saved.root
    aside = _free_folder(root, number)
    (aside / CAPTURES).mkdir(parents=True)
    moved = []
    for index in saved.hangings[h]:
        folder = root / CAPTURES / f"{index:04d}"
        if folder.is_dir():
            os.rename(folder, aside / CAPTURES / folder.name)
            moved.append(index)
    if (root / RESULTS).is_dir():
        os.rename(root / RESULTS, aside / RESULTS)
    if (root / "truth.yaml").is_file():
        shutil.copy2(root / "truth.yaml", aside / "truth.yaml")
    manifest = saved.store.read_manifest()
    journal = manifest.get("hanging_log", [])
    # The decision after the last hanging was made from the captures set aside: it is made
    # again (a hanging before others keeps the decisions that asked for those).
    last = h == len(saved.hangings) - 1
    decided = [entry for entry in journal if last and entry["hanging"] >= number]
    history = {
        "hanging": number,
        "failures": left_out[0]["failures"],
        "set_aside": str(aside.relative_to(root)),
        "captures": moved,
        "decisions": decided,
        "stop_reason": manifest.get("stop_reason"),
    }
    manifest.update(
        status="running",
        left_out_hangings=None,
        pending_rehang=h,
        rescanning=h,
        hanging_log=[entry for entry in journal if entry not in decided],
        quick_alignments=without_passes_from(manifest, h),
        stop_reason=None if last else manifest.get("stop_reason"),
        rescans=[*manifest.get("rescans", []), history],
    )
    saved.store.write_manifest(manifest)
    log.warning(
        "scanning hanging %d again: its %d captures and the results are kept in %s",
        number,
        len(moved),
        aside,
    )
    return open_scan(root)
