"""Configuration changes a command-line flag asks for: the record validates itself, and its error
names the flag the user typed rather than the field's key path."""

from __future__ import annotations

import re
from collections.abc import Callable

from reconstruction.common.errors import ScannerError

_KEY_PATH = re.compile(r"[a-z_][a-z0-9_]*(?:\.[a-z_][a-z0-9_]*)*: ")


def for_flag(flag: str, apply: Callable):
    """`apply()` (a configuration change that validates itself), its ScannerError told in terms
    of the command-line flag that asked for it (the field's key path replaced by the flag)."""
    try:
        return apply()
    except ScannerError as e:
        message = str(e)
        key = _KEY_PATH.match(message)
        if key:
            message = message[key.end() :]
        raise type(e)(f"{flag}: {message}") from None
