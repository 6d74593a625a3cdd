"""`scanner ARGS` run in the test's own process: what a separate process would return (exit
code, standard output, standard error) without its 3-5 s of imports. The tests about a process
itself (a kill, SIGINT, the exit of the interpreter) still start one."""

from __future__ import annotations

import subprocess

import pytest

from scanner.commands.main import main


def scanner(capfd: pytest.CaptureFixture[str], *args) -> subprocess.CompletedProcess:
    """`scanner ARGS` through `main`, its output read at the file descriptors (`capfd`), so a
    library writing to them directly is seen as a separate process's caller would see it."""
    capfd.readouterr()
    argv = [str(a) for a in args]
    try:
        code = main(argv)
    except SystemExit as e:  # argparse: --help, --version and bad options
        code = e.code
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(["scanner", *argv], code, out, err)
