"""What surrounds a running scan in its process: Ctrl-C / SIGTERM finish the current capture
and stop, the scan's log file, and the optional Meshcat viewer."""

from __future__ import annotations

import logging
import os
import signal
from contextlib import contextmanager, suppress
from pathlib import Path


def interruptible(machine):
    """Ctrl-C / SIGTERM ask the machine to stop after the current capture."""

    @contextmanager
    def guard():
        def handler(signum, frame):
            # Only what is safe wherever the signal lands: the flag, and one unbuffered write
            # to the terminal. A log call here re-entered the log record being written when the
            # signal came ("--- Logging error ---" on stderr, now and then); the machine logs
            # the abort at its next state boundary.
            machine.request_abort()
            notice = (
                f"scanner: WARNING: signal {signum}: finishing the current capture, then stopping\n"
            )
            with suppress(OSError):  # no terminal: the scan log still says it stopped
                os.write(2, notice.encode())

        previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in previous.items():
                signal.signal(s, h)

    return guard()


@contextmanager
def log_file(path: Path):
    """Every state transition goes to SCAN_DIR/scan.log (appended on resume); only warnings
    (skipped views, failed captures) reach the terminal, whatever else configured logging."""
    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    console = logging.StreamHandler()
    console.setLevel(logging.WARNING)
    console.setFormatter(logging.Formatter("scanner: %(levelname)s: %(message)s"))
    root = logging.getLogger("scanner")
    saved = root.level, root.propagate
    root.addHandler(handler)
    root.addHandler(console)
    root.setLevel(logging.INFO)
    root.propagate = False
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.removeHandler(console)
        root.setLevel(saved[0])
        root.propagate = saved[1]
        handler.close()


def meshcat_if(enabled: bool):
    if not enabled:
        return None
    from pydrake.geometry import Meshcat

    meshcat = Meshcat()
    print(f"Meshcat: {meshcat.web_url()}", flush=True)
    return meshcat
