"""Reading a YAML file with a user error (not a traceback) when it is missing or malformed."""

from __future__ import annotations

from pathlib import Path

import yaml

from reconstruction.errors import ScannerError


def read_yaml(path: Path, what: str) -> object:
    """The parsed content of `path`; `what` names the file's role in the error message."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except OSError as e:
        raise ScannerError(f"{path}: cannot read {what} ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ScannerError(f"{path}: {what} is not a text file (UTF-8 YAML expected)") from None
    except yaml.YAMLError as e:
        # PyYAML's message spans lines (with a caret under the column); one line for users.
        detail = " ".join(str(e).split())
        raise ScannerError(f"{path}: {what} is not valid YAML ({detail})") from None
