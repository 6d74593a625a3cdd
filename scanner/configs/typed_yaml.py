"""YAML <-> frozen dataclasses: one loader that rejects unknown keys and checks types by field.

The constructor of each dataclass runs, so every `__post_init__` validation applies to loaded
files exactly as to code-built configs.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from pathlib import Path

from reconstruction.common.errors import ScannerError
from reconstruction.common.yaml_files import read_yaml


def _at(where: str, keys: str) -> str:
    """`file: key.path` (the file, then where in it), or the file alone at the top."""
    return f"{where}: {keys}" if keys else where


def _key(keys: str, name: str) -> str:
    return f"{keys}.{name}" if keys else name


def _convert(tp, value, where: str, keys: str, default=None):
    """`value` as type `tp`; `default`: the value the enclosing record has there when the file
    does not say (a nested record's keys the file leaves out keep it)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(inner[0], value, where, keys, default)
        # A choice of types (e.g. a count or a word): the first that takes the value; the
        # record's own check then says what is allowed.
        for tp_k in inner:
            try:
                return _convert(tp_k, value, where, keys)
            except ScannerError:
                continue
        names = " or ".join(getattr(t, "__name__", str(t)) for t in inner)
        raise ScannerError(f"{_at(where, keys)}: expected {names}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        return _from_dict(tp, value, where, keys, default if isinstance(default, tp) else None)
    at = _at(where, keys)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list | tuple):
            raise ScannerError(f"{at}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, where, f"{keys}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ScannerError(f"{at}: expected {len(args)} values, got {len(value)}")
        return tuple(
            _convert(a, v, where, f"{keys}[{i}]") for i, (a, v) in enumerate(zip(args, value))
        )
    if tp is float:
        # No setting is infinite or undefined: a NaN would pass every `<` check as false.
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ScannerError(f"{at}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ScannerError(f"{at}: expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ScannerError(f"{at}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ScannerError(f"{at}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ScannerError(f"{at}: expected a string, got {value!r}")
        return value
    raise TypeError(f"{at}: unsupported field type {tp}")


def from_dict(cls, data, where: str):
    """Build dataclass `cls` from a mapping; missing keys take the defaults (in a nested
    section, the enclosing record's default of that section, not its class's). Errors read
    `where: key.path: what was expected` (`where` is usually the file)."""
    return _from_dict(cls, data, where, "")


# A record's own check names its fields as `section.name`, the section being the record's usual
# key (`views.count`, `handeye.coarse.loss`), or by the bare name at the start of the message;
# the loader knows the real key path of the record in the file and writes that instead.
_DOTTED = re.compile(r"(?<![\w.])(?:[A-Za-z_]\w*\.)+(\w+)(?![\w.])")
_LEADING_NAME = re.compile(r"(\w+)(?=[: ])")


def _with_key_paths(message: str, keys: str, names: set[str]) -> str:
    """`message` of the record at `keys` with each of its fields named by its key path; a
    message naming none is put under the record's own key path."""
    found = [m for m in _DOTTED.finditer(message) if m.group(1) in names]
    named = _DOTTED.sub(
        lambda m: _key(keys, m.group(1)) if m.group(1) in names else m.group(0), message
    )
    leading = _LEADING_NAME.match(named)
    if leading and leading.group(1) in names:
        return _key(keys, leading.group(1)) + named[leading.end() :]
    if found or not keys:
        return named
    last = keys.rsplit(".", 1)[-1]
    if message.startswith(f"{last}:"):
        return f"{keys}{message[len(last) :]}"
    return f"{keys}: {message}"


def _unknown_keys(unknown: list[str], names: set[str]) -> str:
    valid = sorted(names)
    guesses = [m for k in unknown for m in difflib.get_close_matches(k, valid, n=1)]
    hint = f" (did you mean {', '.join(guesses)}?)" if guesses else ""
    return f"unknown key(s) {', '.join(unknown)}{hint}; valid keys: {', '.join(valid)}"


def _field_default(base, field: dataclasses.Field):
    """What a record has in `field` when the file leaves it out: `base`'s value, else the
    field's own default (which may differ from its class's defaults: a recording's stereo
    matcher has a 5 px block, the class 3 px)."""
    if base is not None:
        return getattr(base, field.name)
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None if field.default is dataclasses.MISSING else field.default


def _from_dict(cls, data, where: str, keys: str, base=None):
    if not isinstance(data, dict):
        raise ScannerError(f"{_at(where, keys)}: expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(str(k) for k in set(data) - names)
    if unknown:
        raise ScannerError(f"{_at(where, keys)}: {_unknown_keys(unknown, names)}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs = {}
    for k, v in data.items():
        default = _field_default(base, fields[k])
        nested = default if dataclasses.is_dataclass(default) else None
        kwargs[k] = _convert(hints[k], v, where, _key(keys, k), nested)
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except ScannerError as e:
        raise type(e)(f"{where}: {_with_key_paths(str(e), keys, names)}") from None


def to_dict(obj) -> dict:
    """Plain YAML-ready mapping of a (nested) dataclass."""

    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v) if f.init}
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        return v

    return plain(obj)


def load_yaml_file(cls, path: Path):
    return from_dict(cls, read_yaml(path, "configuration") or {}, str(path))
