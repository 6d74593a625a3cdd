"""The exception types for what the user must act on (bad input, refused results, a full disk).

They live in the leaf package so that every layer (robots, planners, scanner) can raise them
without breaking the one-way dependencies; the CLI turns each into one line on stderr and its
exit code. Programming errors stay ordinary exceptions with tracebacks.
"""


class ScannerError(Exception):
    """A user error; the message names the file/field and what was expected. Exit code 2."""

    exit_code = 2


class RefusedResultError(ScannerError):
    """The input was usable but the result failed its plausibility checks; nothing was written
    that looks like a result. Exit code 3."""

    exit_code = 3


class StorageError(ScannerError):
    """Writing to disk failed (full disk, permissions); what was written before is kept.
    Exit code 1."""

    exit_code = 1
