"""Freed memory kept by the process for reuse, so that large arrays do not fault in fresh pages
each time they are made.

glibc's allocator hands every block above its mmap threshold (which it raises by itself to at
most 32 MiB) back to the kernel as soon as it is freed, and trims the heap's free top above
twice that. The reconstruction makes and drops arrays of tens of MiB again and again (a fused
cloud of 1.8 M points is 43 MiB a coordinate array), so each of them faulted in every page
anew; on the virtual machines measured, a page fault costs a few microseconds, which made such
a step several times slower than its arithmetic (an array of 43 MiB written and doubled: 13 ->
5 ms). With both thresholds raised, freed blocks stay in the heap and are reused. The price is
resident memory that stays near its peak instead of falling between stages (a 48-view scan's
peak 1.7 -> 1.9 GB).

`keep_freed_memory` sets this for the process (the command line, the Poisson solver process)
and, through the environment, for every process it starts. Elsewhere than glibc it does
nothing."""

from __future__ import annotations

import ctypes
import os

# Above either, a block is still returned to the kernel: the largest arrays (a few GiB) would
# otherwise stay resident for the whole run.
MMAP_THRESHOLD_BYTES = 1 << 30
TRIM_THRESHOLD_BYTES = 1 << 30
ENVIRONMENT = {
    "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD_BYTES),
    "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD_BYTES),
}
_M_TRIM_THRESHOLD = -1  # glibc's malloc.h
_M_MMAP_THRESHOLD = -3


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds in this process and, through the environment,
    in the processes it starts. A user's own MALLOC_MMAP_THRESHOLD_ or MALLOC_TRIM_THRESHOLD_
    is left as it is (glibc read it at the start).

    Returns:
        Whether this process's allocator now keeps freed memory: False without glibc, or where
        the user chose other thresholds."""
    if any(os.environ.get(name, value) != value for name, value in ENVIRONMENT.items()):
        return False
    os.environ.update(ENVIRONMENT)
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS): its allocator, its choices
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
