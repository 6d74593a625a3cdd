"""Open3D imported without its notebook viewer.

`import open3d` imports `open3d.visualization.draw_plotly`, a viewer for Jupyter, and with it
Dash, Plotly and IPython: about half of what importing Open3D costs (0.4 of 0.75 CPU s,
measured), paid again by every process that reconstructs (a command, each Poisson solver child,
each Ray worker of a batch). Nothing in this project draws with it. A stand-in takes the module's
place before Open3D is imported; calling one of its functions imports the real module then, so
the viewer still works for whoever wants it.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable

_VIEWER = "open3d.visualization.draw_plotly"
# What open3d/visualization/__init__.py takes from the viewer's module (Open3D 0.20).
_FUNCTIONS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _real_viewer() -> types.ModuleType:
    module = sys.modules.get(_VIEWER)
    if module is None or getattr(module, "_stand_in", False):
        sys.modules.pop(_VIEWER, None)
        module = importlib.import_module(_VIEWER)
    return module


def _deferred(name: str) -> Callable:
    def call(*args, **kwargs):
        return getattr(_real_viewer(), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"Open3D's `{name}`, its module imported at the first call."
    return call


def defer_open3d_viewer() -> None:
    """Put the stand-in in place, unless Open3D (or its viewer) is imported already."""
    if "open3d" in sys.modules or _VIEWER in sys.modules:
        return
    stand_in = types.ModuleType(_VIEWER, "Stand-in for Open3D's notebook viewer (not imported).")
    stand_in._stand_in = True
    for name in _FUNCTIONS:
        setattr(stand_in, name, _deferred(name))
    sys.modules[_VIEWER] = stand_in
