"""The process keeps freed memory for reuse (reconstruction.common.memory): a large array made
again after it was freed faults in no fresh pages, and the processes started after inherit it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from reconstruction.common.memory import ENVIRONMENT, keep_freed_memory

ROOT = Path(__file__).resolve().parents[1]

# 64 MiB made, freed, made again: the page faults of the second time.
FAULTS = """
import resource, sys
import numpy as np
from reconstruction.common.memory import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else None
a = np.ones(8 << 20); del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(8 << 20); del a
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _run(how: str, env: dict[str, str]) -> tuple[str, int]:
    out = subprocess.run(
        [sys.executable, "-c", FAULTS, how], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    kept, faults = out.stdout.split()
    return kept, int(faults)


def _plain_environment() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ENVIRONMENT}
    return {**env, "PYTHONPATH": str(ROOT)}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_a_freed_array_is_made_again_without_fresh_pages():
    _, plain = _run("plain", _plain_environment())
    kept, again = _run("keep", _plain_environment())
    assert kept == "True"
    # 64 MiB is 16384 pages of 4 KiB (32 huge pages): each faulted in anew without; none with.
    assert plain >= 32 and again < plain / 8, (plain, again)
    # A process started from one that keeps freed memory keeps it too (the environment).
    _, child = _run("plain", {**_plain_environment(), **ENVIRONMENT})
    assert child < plain / 8, (plain, child)


def test_a_users_own_thresholds_are_left_alone(monkeypatch):
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "123")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    assert keep_freed_memory() is False
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "123"
    assert "MALLOC_MMAP_THRESHOLD_" not in os.environ
