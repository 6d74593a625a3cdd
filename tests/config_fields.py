"""Every field of a configuration record, walked from its dataclass, with one bad value for each:
what the table-driven configuration tests write into a file to see it refused at load."""

from __future__ import annotations

import dataclasses
import types
import typing

# A value of the right type that is still wrong, by the field's type. A float field is a length,
# time, threshold or gain, never negative unless it is listed in the record's overrides.
BAD_BY_TYPE = {float: -1.0, int: -1, bool: "maybe", str: "no-such-value"}


def _without_none(tp):
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(inner) == 1:
            return inner[0]
    return tp


def leaf_fields(cls, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], object]]:
    """(key path, type) of every field that is not itself a record, nested records walked."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = _without_none(hints[f.name])
        if dataclasses.is_dataclass(tp):
            out += leaf_fields(tp, (*prefix, f.name))
        else:
            out.append(((*prefix, f.name), tp))
    return out


def bad_value(path: tuple[str, ...], tp, overrides: dict):
    """The bad value the table writes at `path`: an override, else one by type (a tuple of
    numbers with a number too few, a list of names with an unknown one)."""
    key = ".".join(path)
    if key in overrides:
        return overrides[key]
    if tp in BAD_BY_TYPE:
        return BAD_BY_TYPE[tp]
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            if args[0] in BAD_BY_TYPE:
                return [BAD_BY_TYPE[args[0]]]
        elif all(a is float for a in args):
            return [0.0] * (len(args) - 1)
    raise KeyError(f"{key}: no bad value for {tp}; add one to the overrides")


def nested(path: tuple[str, ...], value) -> dict:
    for key in reversed(path):
        value = {key: value}
    return value
