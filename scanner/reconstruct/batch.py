"""`scanner reconstruct SCAN_DIR SCAN_DIR ...`: one Ray task per scan, on a local Ray by default
or on an existing cluster (`--ray-address`), a line per finished scan, and a failed scan
reported without stopping the others.

Each task runs exactly what a single `scanner reconstruct SCAN_DIR` runs (`reconstruct_one`),
on one thread per library (Ray's OMP_NUM_THREADS=1 for a one-CPU task), so two scans share two
cores without oversubscribing them; the results do not depend on the thread count (the Poisson
solve is single-threaded, the TSDF mesh is put in a canonical order), so a batch gives the same
results as running the scans one by one. On a cluster, its nodes need this package
installed and the scan directories at the same paths.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from reconstruction.common.errors import ScannerError


@dataclass(frozen=True)
class BatchOutcome:
    """One scan's end: its report and results folder, or why it failed."""

    scan_dir: Path
    report: dict | None
    results_dir: Path | None
    error: str = ""

    @property
    def ok(self) -> bool:
        return not self.error


def _task_outcome(run: Callable, scan_dir: str, options) -> dict:
    """In the worker: a user error becomes a message, not a Ray traceback."""
    try:
        result = run(Path(scan_dir), options)
    except ScannerError as e:
        return {"error": " ".join(str(e).split())}
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        return {"error": f"{where}{e.strerror or e}"}
    return {"report": result.report, "results_dir": str(result.results_dir)}


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """A Ray head given as HOST:PORT must accept a connection, else a clear error at once
    (Ray itself waits about a minute before it gives up)."""
    if address in ("auto", "local"):
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ScannerError(f"--ray-address {address}: expected HOST:PORT (or ray://HOST:PORT)")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            return
    except OSError as e:
        raise ScannerError(
            f"--ray-address {address}: no Ray head answers there ({e}); start one with "
            "`ray start --head` or leave the option out for a local Ray"
        ) from e


def run_batch(
    scan_dirs: Sequence[Path],
    run: Callable,
    options,
    workers: int,
    ray_address: str | None,
    on_done: Callable[[BatchOutcome], None],
) -> list[BatchOutcome]:
    """`run(scan_dir, options)` (returning an object with .report and .results_dir) as one Ray
    task per scan, at most `workers` at a time; `on_done` hears each scan as it finishes, in
    the order they finish. Returns the outcomes in the order of `scan_dirs`."""
    import ray

    if ray_address is not None:
        check_ray_address(ray_address)
    started_here = not ray.is_initialized()
    if started_here:
        try:
            ray.init(
                address=ray_address,
                num_cpus=None if ray_address is not None else workers,
                include_dashboard=False,
                log_to_driver=False,
                logging_level="ERROR",
            )
        except (ConnectionError, RuntimeError, ValueError) as e:
            where = "locally" if ray_address is None else f"at {ray_address}"
            message = " ".join(str(e).split())
            raise ScannerError(f"--ray-address: could not start Ray {where}: {message}") from e
    task = ray.remote(num_cpus=1, max_retries=0)(_task_outcome)
    outcomes: dict[int, BatchOutcome] = {}
    try:
        pending: dict = {}
        queue = list(enumerate(scan_dirs))
        while queue or pending:
            while queue and len(pending) < workers:
                k, scan_dir = queue.pop(0)
                pending[task.remote(run, str(scan_dir), options)] = k
            [ref], _ = ray.wait(list(pending), num_returns=1)
            k = pending.pop(ref)
            outcomes[k] = _outcome(ray, ref, Path(scan_dirs[k]))
            on_done(outcomes[k])
    finally:
        if started_here:
            ray.shutdown()
    return [outcomes[k] for k in range(len(scan_dirs))]


def _outcome(ray, ref, scan_dir: Path) -> BatchOutcome:
    try:
        got = ray.get(ref)
    except ray.exceptions.WorkerCrashedError:
        return BatchOutcome(
            scan_dir, None, None, "the worker process died (killed or out of memory)"
        )
    except ray.exceptions.RayError as e:
        cause = getattr(e, "cause", None) or e
        return BatchOutcome(
            scan_dir, None, None, f"{type(cause).__name__}: {cause}".splitlines()[0]
        )
    if "error" in got:
        return BatchOutcome(scan_dir, None, None, got["error"])
    return BatchOutcome(scan_dir, got["report"], Path(got["results_dir"]))
