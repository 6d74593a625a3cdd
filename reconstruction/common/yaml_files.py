"""Reading and writing YAML: a user error (not a traceback) when a file is missing or
malformed, and libyaml's C parser and emitter where PyYAML has them.

The C versions read and write the same data and text as the pure-Python ones about ten times
faster; a scan's manifest (about 50 kB for 24 views) is read several times during a scan.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from reconstruction.common.errors import ScannerError

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def yaml_text(data: object) -> str:
    """`data` as YAML, keys in their given order (what yaml.safe_dump(sort_keys=False) gives)."""
    return yaml.dump(data, Dumper=_DUMPER, sort_keys=False)


def read_yaml(path: Path, what: str) -> object:
    """The parsed content of `path`; `what` names the file's role in the error message."""
    path = Path(path)
    try:
        return yaml.load(path.read_text(), Loader=_LOADER)
    except OSError as e:
        raise ScannerError(f"{path}: cannot read {what} ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ScannerError(f"{path}: {what} is not a text file (UTF-8 YAML expected)") from None
    except yaml.YAMLError as e:
        # PyYAML's message spans lines (with a caret under the column); one line for users.
        detail = " ".join(str(e).split())
        raise ScannerError(f"{path}: {what} is not valid YAML ({detail})") from None
