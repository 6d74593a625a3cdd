"""Results folders: chosen so that no earlier result is replaced, and written under a hidden
name that is renamed only when everything is in it, so that a run killed half-way leaves nothing
that looks like a result (the captures use the same scheme)."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from reconstruction.common.errors import ScannerError, StorageError


def holds_result(folder: Path, marker: str) -> bool:
    """Whether `folder` holds a finished result (its `marker` file is written last)."""
    return (Path(folder) / marker).is_file()


def free_results_dir(root: Path, marker: str, name: str = "results") -> Path:
    """ROOT/NAME while it holds no result, else the first free ROOT/NAME-N."""
    candidate, n = Path(root) / name, 1
    while holds_result(candidate, marker):
        n += 1
        candidate = Path(root) / f"{name}-{n}"
    return candidate


def latest_results_dir(root: Path, marker: str, name: str = "results") -> Path | None:
    """The newest of ROOT/NAME, ROOT/NAME-2, ... that holds a result (the highest N; runs
    number their folders upwards, `free_results_dir`), or None."""
    found = []
    for path in Path(root).glob(f"{name}*"):
        suffix = path.name[len(name) :]
        if suffix == "":
            n = 1
        elif suffix.startswith("-") and suffix[1:].isdigit():
            n = int(suffix[1:])
        else:
            continue
        if holds_result(path, marker):
            found.append((n, path))
    return max(found)[1] if found else None


def require_replaceable(out: Path, marker: str, force: bool, what: str) -> None:
    """Refuse an --out that holds a finished result unless --force."""
    if holds_result(out, marker) and not force:
        raise ScannerError(
            f"{out}: holds a {what} already; choose another --out, or --force to replace it"
        )


def require_new_file(path: Path, flag: str, force: bool) -> None:
    """Refuse, before any work, a file `path` that exists (unless `force`) or that cannot be
    written (its folder is probed like `require_creatable`)."""
    path = Path(path)
    if path.is_dir():
        raise ScannerError(f"{flag} {path}: is a folder, expected a file name")
    if path.exists() and not force:
        raise ScannerError(
            f"{flag} {path}: exists already; choose another {flag}, or --force to replace it"
        )
    require_creatable(path.parent, flag)


def require_creatable(path: Path, flag: str) -> None:
    """Fail before any work when `path` (a folder to write into) cannot be made or written: a
    probe folder is created in it and removed again, with any parents it needed."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ScannerError(f"{flag} {path}: is a file, expected a folder")
    created = [p for p in (path, *path.parents) if not p.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
        os.rmdir(tempfile.mkdtemp(prefix=".probe-", dir=path))
    except OSError as e:
        raise ScannerError(f"{flag} {path}: cannot write there ({e.strerror})") from None
    finally:
        for p in created:  # deepest first
            with suppress(OSError):
                p.rmdir()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_stale_partials(parent: Path, name: str) -> None:
    """Partial folders of runs that were killed (their process is gone)."""
    for path in parent.glob(f".{name}.partial-*"):
        pid = path.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not _pid_alive(int(pid)):
            shutil.rmtree(path, ignore_errors=True)


def storage_error(path: Path, e: OSError) -> StorageError:
    reason = e.strerror or str(e)
    if e.errno == errno.ENOSPC:
        reason = "no space left on the device"
    return StorageError(f"{path}: could not write ({reason})")


@contextmanager
def staged_folder(final: Path, marker: str, own: tuple[str, ...] = ()) -> Iterator[Path]:
    """A hidden sibling of `final` to write into; renamed to `final` when the block succeeds
    (an existing `final` is moved aside first and removed only after the rename), removed when
    it fails. The caller decides beforehand whether an earlier result in `final` may be
    replaced; whatever else `final` holds is never replaced: a results folder is known by its
    `marker` file (written last), and `own` names files the caller wrote there before and
    carries into the new folder (a scan's own report, before its reconstruction)."""
    final = Path(final)
    parent = final.parent
    if final.is_dir() and not holds_result(final, marker):
        foreign = [p.name for p in final.iterdir() if p.name not in own and p.name[0] != "."]
        if foreign:
            raise ScannerError(
                f"{final}: holds {', '.join(sorted(foreign)[:3])} and no result to replace; "
                "nothing written"
            )
    try:
        parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_partials(parent, final.name)
        staging = parent / f".{final.name}.partial-{os.getpid()}"
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir()
    except OSError as e:
        raise storage_error(final, e) from None
    try:
        yield staging
        old = parent / f".{final.name}.old-{os.getpid()}"
        if final.exists():
            os.rename(final, old)
        os.rename(staging, final)
        shutil.rmtree(old, ignore_errors=True)
    except OSError as e:
        shutil.rmtree(staging, ignore_errors=True)
        raise storage_error(final, e) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
