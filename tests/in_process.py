"""`scanner ARGS` run in the test's own process: what a separate process would return (exit
code, standard output, standard error) without its 3-5 s of imports. The tests about a process
itself (a kill, SIGINT, the exit of the interpreter) still start one."""

from __future__ import annotations

import contextlib
import io
import subprocess

import pytest

from scanner.commands.main import main


def _exit_code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse: --help, --version and bad options
        return e.code


def scanner(capfd: pytest.CaptureFixture[str], *args) -> subprocess.CompletedProcess:
    """`scanner ARGS` through `main`, its output read at the file descriptors (`capfd`), so a
    library writing to them directly is seen as a separate process's caller would see it."""
    argv = [str(a) for a in args]
    capfd.readouterr()
    code = _exit_code(argv)
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(["scanner", *argv], code, out, err)


def scanner_in_fixture(*args) -> subprocess.CompletedProcess:
    """The same for a fixture shared by several tests (where no capfd is): what `main` printed
    through sys.stdout and sys.stderr."""
    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = _exit_code(argv)
    return subprocess.CompletedProcess(["scanner", *argv], code, out.getvalue(), err.getvalue())
