"""The one exception type for user errors (bad input, bad files, bad settings).

It lives in the leaf package so that every layer (robots, planners, scanner) can raise it without
breaking the one-way dependencies; the CLI turns it into one line on stderr and exit code 2.
Programming errors stay ordinary exceptions with tracebacks.
"""


class ScannerError(Exception):
    """A user error; the message names the file/field and what was expected."""
