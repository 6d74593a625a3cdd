"""The command line's parser class (usage errors in one line), the making of a subcommand's
parser with its runner, argument types shared by the subcommands' parsers (they turn a bad value
into a usage error naming the option, exit 2), the defaults that help reads from the
configuration records, and the options several subcommands have."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn


class ScannerArgumentParser(argparse.ArgumentParser):
    """argparse with one-line usage errors: `PROG: error: MESSAGE (see PROG --help)`, exit 2,
    instead of the whole usage block above the message."""

    def error(self, message: str) -> NoReturn:
        message = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_args(self, args=None, namespace=None):
        # A subcommand's unknown option is reported by the subcommand, which points at its help.
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            self._parser_of(parsed).error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed

    def _parser_of(self, parsed: argparse.Namespace) -> argparse.ArgumentParser:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = getattr(parsed, action.dest, None)
                if chosen in action.choices:
                    return action.choices[chosen]
        return self


@dataclasses.dataclass(frozen=True)
class ConfigDefault:
    """The default of a configuration field for a help text, read from the record itself when
    help is printed: the configuration modules import Drake and Open3D, which building the parser
    (for every command, --version and usage errors) should not wait for.

    `record` is 'module:Class' (built with no arguments), `key` the dotted field path in it,
    `show` turns the value into the words of the help."""

    record: str
    key: str
    show: Callable[[Any], str] = str

    def value(self):
        module, name = self.record.split(":")
        value = getattr(importlib.import_module(module), name)()
        for part in self.key.split("."):
            value = getattr(value, part)
        return value

    def __str__(self) -> str:
        return self.show(self.value())


def add_command(sub, name: str, run: str, help: str, description: str) -> argparse.ArgumentParser:
    """The parser of subcommand `name` in `sub` (the subparsers), with its runner named as
    'module:function': scanner.commands.main imports the runner only when the command runs, so that
    building the parser for every command stays light."""
    parser = sub.add_parser(name, help=help, description=description)
    parser.set_defaults(run=run)
    return parser


def add_config_file_argument(parser: argparse.ArgumentParser, help: str) -> None:
    """--config FILE, a YAML file of settings; `help` says which settings, and what applies
    without it."""
    parser.add_argument("--config", type=path_arg, help=help)


def add_config_option(parser, *flags: str, config: ConfigDefault, **options) -> argparse.Action:
    """An option whose default comes from the configuration: its help writes that default as
    `%(config_default)s` (argparse expands help with the action's attributes)."""
    action = parser.add_argument(*flags, **options)
    action.config_default = config
    return action


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text}")
    return v


def finite_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
    return v


class LengthOption(argparse.Action):
    """A length option (metavar LENGTH): a number in metres, or with a unit (`0.5mm`); stores
    metres in `dest` and the text as typed in the namespace's `typed` mapping, so that a value
    refused later (e.g. larger than the object) is quoted as the user wrote it."""

    def __init__(self, option_strings, dest, **kwargs):
        kwargs.setdefault("metavar", "LENGTH")
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from reconstruction.common.errors import ScannerError
        from reconstruction.common.lengths import parse_length

        try:
            metres = parse_length(values)
        except ScannerError as e:
            parser.error(f"argument {option_string}: {e}")
        setattr(namespace, self.dest, metres)
        namespace.typed = {**getattr(namespace, "typed", {}), self.dest: values}


def typed_text(args: argparse.Namespace, dest: str) -> str:
    """How the user typed the length option `dest` (its value in metres when not given)."""
    return getattr(args, "typed", {}).get(dest, f"{getattr(args, dest)}")


LENGTH_HELP = "a number in metres, or with a unit: 0.5mm, 2cm, 0.0005m"


def hangings_arg(text: str) -> int | str:
    """--hangings: 'auto' or a count (the configuration checks its range)."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or an integer, got '{text}'") from None


def seconds_list(text: str) -> tuple[float, ...]:
    """Comma-separated times in seconds, each finite and >= 0."""
    values = []
    for part in text.split(","):
        try:
            v = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected seconds such as 4,12.5, got '{text}'"
            ) from None
        if not (math.isfinite(v) and v >= 0):
            raise argparse.ArgumentTypeError(f"expected times >= 0 s, got {part.strip()}")
        values.append(v)
    return tuple(values)


def worker_count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if not 1 <= v <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"expected 1 to {MAX_WORKERS}, got {text}")
    return v


MAX_WORKERS = 1024


def path_arg(text: str) -> Path:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got an empty string")
    return Path(text)


def name_arg(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a name, got an empty string")
    return text


def mesh_formats_arg(text: str) -> str:
    """--formats: a comma-separated list of mesh file formats; returned as given (the command
    turns it into suffixes), so a bad name is a usage error naming the option."""
    from reconstruction.surfaces.meshes import MESH_SUFFIXES

    names = [f.strip().lstrip(".").lower() for f in text.split(",")]
    valid = [s.lstrip(".") for s in MESH_SUFFIXES]
    bad = [n for n in names if n not in valid]
    if bad:
        raise argparse.ArgumentTypeError(
            f"unknown mesh format(s) {', '.join(repr(n) for n in bad)}; "
            f"expected a comma-separated list from {', '.join(valid)}"
        )
    return text


def show_formats(suffixes: tuple[str, ...]) -> str:
    return ",".join(s.lstrip(".") for s in suffixes)


# A configuration check's message starts with the field's key path ("views.count: expected
# ..."); the command line names the flag instead.


def add_output_arguments(
    parser: argparse.ArgumentParser,
    out_help: str,
    force_help: str,
    *,
    required: bool = False,
    **out_options,
) -> None:
    """--out, where the command writes, and --force, which lets it replace what is there;
    `out_options` go to --out (argparse's dest, metavar)."""
    parser.add_argument("--out", type=path_arg, required=required, help=out_help, **out_options)
    parser.add_argument("--force", action="store_true", help=f"{force_help} (default: off)")


def add_seed_argument(parser: argparse.ArgumentParser, default: int | None = None) -> None:
    """--seed of the simulated errors (robots.simulation.truth.ErrorModel); without `default` the
    configuration's seed applies."""
    help_text = "seed of the simulated error model (default %(config_default)s)"
    if default is not None:
        help_text = "seed of the simulated error model (default %(default)s)"
    add_config_option(
        parser,
        "--seed",
        type=int,
        default=default,
        help=help_text,
        config=ConfigDefault("robots.simulation.truth:ErrorModel", "seed"),
    )


def add_driver_argument(parser: argparse.ArgumentParser, what: str, note: str = "") -> None:
    """--driver: real hardware instead of the Drake simulation (`what` runs on it; `note` ends
    the help)."""
    parser.add_argument(
        "--driver",
        type=name_arg,
        metavar="MODULE:FACTORY",
        help=f"{what} with real hardware: factory(config) returns "
        "robots.drivers.interfaces.Hardware "
        f"(default: the Drake simulation){note}",
    )
