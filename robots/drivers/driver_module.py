"""The factory a `--driver MODULE:FACTORY` value names, found as `python -m` would find it.

An installed `scanner` console script puts its own folder, not the working folder, first on the
import path, so a user's `my_cell/rx60.py` beside them would not import as `my_cell.rx60`. A
module that does not import from the path is therefore looked for in the working folder (a
package or a `.py` file there), as `python -m scanner` and `python my_script.py` would see it;
the import path is not changed.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path

from reconstruction.common.errors import ScannerError


def _import_from_working_folder(top: str) -> bool:
    """Import the top-level package or module `top` from the working folder; False when the
    folder has none."""
    spec = importlib.machinery.PathFinder.find_spec(top, [str(Path.cwd())])
    if spec is None or spec.loader is None:
        return False
    module = importlib.util.module_from_spec(spec)
    sys.modules[top] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[top]
        raise
    return True


def _import(module_name: str):
    top = module_name.split(".")[0]
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name != top or not _import_from_working_folder(top):
            raise
    return importlib.import_module(module_name)


def driver_factory(spec: str) -> Callable:
    """The callable `spec` ('package.module:factory') names, imported now; a ScannerError
    (without the option's name, which the caller adds) when it cannot be."""
    module_name, _, attribute = str(spec).partition(":")
    if not module_name or not attribute:
        raise ScannerError(f"expected 'package.module:factory', got '{spec}'")
    try:
        module = _import(module_name)
    except ImportError as e:
        raise ScannerError(
            f"cannot import '{module_name}' ({e}); it is looked for on the Python path and in "
            f"the working folder ({Path.cwd()})"
        ) from None
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise ScannerError(f"'{module_name}' has no callable '{attribute}'")
    return factory
