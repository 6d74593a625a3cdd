"""The layering: scanner -> planners -> robots, scanner -> reconstruction, and reconstruction is
pure numeric code (no Drake, no upper layer); no module imports itself back through others."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("scanner", "planners", "robots", "reconstruction")
# What each package may import (besides itself).
ALLOWED = {
    "reconstruction": set(),
    "robots": {"reconstruction"},
    "planners": {"robots", "reconstruction"},
    "scanner": {"planners", "robots", "reconstruction"},
}

CHECK = """
import importlib, pkgutil, sys
import reconstruction
names = [m.name for m in pkgutil.walk_packages(reconstruction.__path__, "reconstruction.")]
for name in names:
    importlib.import_module(name)
assert "reconstruction.stereo.matching" in names, names
assert "reconstruction.calibration.eye_in_hand" in names, names
upper = ("pydrake", "robots", "planners", "scanner")
leaked = sorted(m for m in sys.modules if m.split(".")[0] in upper)
print(len(names), leaked)
"""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in the file (function-level imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        found |= {n for n in names if n in modules}
    return found


def test_reconstruction_imports_no_drake_and_no_upper_layer():
    result = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    count, leaked = result.stdout.split(maxsplit=1)
    assert int(count) >= 20  # every module of every subpackage was imported
    assert leaked.strip() == "[]"


def test_packages_import_only_the_layers_below():
    modules = _modules()
    wrong = []
    for name, path in modules.items():
        package = name.split(".")[0]
        for target in _imports(path, modules):
            other = target.split(".")[0]
            if other != package and other not in ALLOWED[package]:
                wrong.append(f"{name} -> {target}")
    assert not wrong, wrong


def test_no_import_cycle():
    modules = _modules()
    graph = {name: _imports(path, modules) - {name} for name, path in modules.items()}
    # A package's __init__ is imported on the way to any of its modules; leave those edges out.
    graph = {n: {t for t in ts if not n.startswith(t + ".")} for n, ts in graph.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, cycles


def test_opencv_is_a_4x_release_with_hand_eye_calibration():
    """opencv-python-headless 5.0's bindings lack calibrateHandEye, which calibration needs."""
    import cv2

    major, minor = (int(part) for part in cv2.__version__.split(".")[:2])
    assert major == 4 and minor >= 10
    assert hasattr(cv2, "calibrateHandEye")
    assert hasattr(cv2, "STEREO_SGBM_MODE_SGBM_3WAY")


# scanner's own packages, from the top down: each imports only packages of lower rows (the
# commands sit above every concept; the scan directory and the configurations below what reads
# them). A newcomer reads the package list in this order as the pipeline runs.
SCANNER_LAYERS = (
    ("commands",),
    ("calibrate", "check_cell", "plan_only"),
    ("scan",),
    ("recordings",),
    ("reconstruct", "inspect"),
    ("scan_dir",),
    ("configs",),
    ("monitor",),
    ("reports",),
)


def test_scanner_packages_import_only_the_rows_below():
    rank = {name: row for row, names in enumerate(SCANNER_LAYERS) for name in names}
    modules = _modules()
    packages = {n.split(".")[1] for n in modules if n.startswith("scanner.") and n.count(".") > 1}
    assert packages == set(rank), "every scanner package has its row"
    wrong = []
    for name, path in modules.items():
        parts = name.split(".")
        if parts[0] != "scanner" or len(parts) < 3:
            continue
        for target in _imports(path, modules):
            other = target.split(".")
            outside = other[0] == "scanner" and len(other) > 1 and other[1] != parts[1]
            if outside and rank[other[1]] <= rank[parts[1]]:
                wrong.append(f"{name} -> {target}")
    assert not wrong, wrong
