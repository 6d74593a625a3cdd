"""`scanner view RESULT_DIR`: open a result's 3D page (model.html) in a browser, or print
where it is when there is no graphical browser."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from reconstruction.common.errors import ScannerError
from scanner.commands.arguments import add_command, path_arg


def add_view_parser(sub) -> None:
    view = add_command(
        sub,
        "view",
        "scanner.commands.view:run_view_command",
        help="open a result's 3D page (model.html) in a browser",
        description="Open model.html, the 3D page every scan, reconstruction, merge and "
        "inspection writes beside its summary.md, in the default browser (it needs no network "
        "or server); without a graphical browser, print its path. RESULT_DIR: a results or "
        "inspection folder, or a scan directory (its newest results folder). Exit code 2 when "
        "there is no page to show.",
    )
    view.add_argument(
        "result_dir",
        type=path_arg,
        metavar="RESULT_DIR",
        help="a scan directory, a results folder or an inspection folder",
    )
    view.add_argument(
        "--no-browser",
        action="store_true",
        help="only print the page's path, do not open a browser (default: off: open it when "
        "there is a graphical browser)",
    )


def model_page_of(target: Path) -> Path:
    """The page to show for `target` (see the parser's help); a ScannerError saying what to
    run when there is none."""
    from scanner.inspect.inspection import INSPECTION_MARKER
    from scanner.reconstruct.stages import RECONSTRUCTION_MARKER
    from scanner.reports.model_page import PAGE_NAME
    from scanner.scan_dir.results_folder import holds_result, latest_results_dir

    target = Path(target)
    if not target.is_dir():
        raise ScannerError(f"{target}: not a folder; expected a scan directory or a results folder")
    if (target / "scan.yaml").is_file():
        results = latest_results_dir(target, RECONSTRUCTION_MARKER)
        if results is None:
            raise ScannerError(
                f"{target}: no reconstruction in this scan directory yet; make one with: "
                f"scanner reconstruct {target}"
            )
        scan_dir = target
    elif holds_result(target, RECONSTRUCTION_MARKER) or holds_result(target, INSPECTION_MARKER):
        results = target
        scan_dir = target.parent if (target.parent / "scan.yaml").is_file() else None
    else:
        raise ScannerError(
            f"{target}: not a scan directory, a results folder or an inspection folder (found "
            f"no scan.yaml, {RECONSTRUCTION_MARKER} or {INSPECTION_MARKER})"
        )
    page = results / PAGE_NAME
    if not page.is_file():
        if holds_result(results, INSPECTION_MARKER):
            again = "scanner inspect MODEL --reference CAD_FILE"
        else:
            again = f"scanner reconstruct {scan_dir or 'SCAN_DIR'}"
        raise ScannerError(
            f"{results}: has no {PAGE_NAME} (written before the 3D page existed, or its writing "
            f"failed); make a new result with: {again}"
        )
    return page


def _graphical_session() -> bool:
    """Whether a browser can show a page here: always on macOS and Windows, on other systems
    only with a display (without one, Python's webbrowser would pick a text browser, which
    cannot draw WebGL)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


# How long a browser command may take to hand the page over (xdg-open, open) before it counts as
# started; one that fails (no browser behind it, no display it can use) exits within this.
BROWSER_START_S = 3.0


def browser_started(url: str, wait_s: float = BROWSER_START_S) -> bool:
    """Whether a browser was started on `url`. Python's webbrowser reports a launcher such as
    xdg-open as started the moment it runs, even when it then fails (no browser, a display
    that does not work); such a command is run here and counts as started only when it exits
    0, or is still running (the browser itself) after `wait_s`."""
    import subprocess
    import webbrowser

    try:
        controller = webbrowser.get()
    except webbrowser.Error:
        return False
    args = getattr(controller, "args", None)
    if args is None:  # the platform's own call (macOS, Windows): it says whether it worked
        try:
            return bool(controller.open(url))
        except webbrowser.Error:
            return False
    command = [controller.name, *(a.replace("%s", url) for a in args)]
    try:
        launched = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    except OSError:
        return False
    try:
        return launched.wait(timeout=wait_s) == 0
    except subprocess.TimeoutExpired:
        return True


def run_view_command(args: argparse.Namespace) -> int:
    page = model_page_of(args.result_dir).resolve()
    if not args.no_browser and _graphical_session() and browser_started(page.as_uri()):
        print(f"opened: {page}")
    else:
        print(f"model page: {page}")
    return 0
