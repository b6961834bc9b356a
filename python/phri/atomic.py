"""Atomic file writes: a file that phri writes is either its old content or its new content, never a
torn mix, even when the process is killed or the machine loses power mid-write.

The data go to a temporary file in the same folder (``NAME.partial``: same file system, so the
rename is atomic; a leftover one marks a write that never finished), which is flushed and fsync'ed,
then renamed over the target with :func:`os.replace`; the folder is fsync'ed too (where the system
allows it) so that the rename itself survives a crash.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path

__all__ = ["LOCK_SUFFIX", "PARTIAL_SUFFIX", "exclusive", "partial_path", "write_atomic"]

#: Suffix of the lock file beside a file that several processes update (:func:`exclusive`).
LOCK_SUFFIX = ".lock"

#: Suffix of the temporary file a write goes through.
PARTIAL_SUFFIX = ".partial"


def partial_path(path: Path) -> Path:
    """The temporary file a write of `path` goes through (a leftover one is an unfinished write)."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


def _fsync_folder(folder: Path) -> None:
    """Makes a rename in `folder` durable; a no-op where folders cannot be opened (Windows)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_atomic(path: str | Path, data: bytes, *, overwrite: bool = True) -> Path:
    """Writes `data` to `path` atomically and durably; returns `path`.

    With `overwrite` False an existing `path` is a :class:`FileExistsError` and nothing is written
    (for files that are written once, such as episode logs): the temporary file is hard-linked to
    `path`, which fails rather than replace a file that appeared meanwhile."""
    path = Path(path)
    if not overwrite and path.exists():
        raise FileExistsError(f"{path} exists; phri never overwrites it")
    tmp = partial_path(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            _link_new(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)
    return path


def _link_new(tmp: Path, path: Path) -> None:
    """Gives `tmp` the name `path` only if no file has it (atomically where hard links exist)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(f"{path} exists; phri never overwrites it") from None
    except OSError:  # a file system without hard links: the caller is the folder's only writer
        if path.exists():
            raise FileExistsError(f"{path} exists; phri never overwrites it") from None
        os.replace(tmp, path)
        return
    tmp.unlink()


@contextlib.contextmanager
def exclusive(path: str | Path, *, timeout: float = 30.0) -> Iterator[None]:
    """Holds an exclusive advisory lock for updating `path` (read, check, rewrite) while the block
    runs, so that concurrent updates of one file queue instead of losing each other's rows. The lock
    is on ``NAME.lock`` beside it (the file itself is replaced by each atomic write, so it cannot
    carry the lock); waits at most `timeout` [s], then raises :class:`TimeoutError`."""
    path = Path(path)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no advisory lock
        yield
        return
    fd = os.open(path.with_name(path.name + LOCK_SUFFIX), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TimeoutError(
                        f"{path}: another process has been updating it for more than {timeout:g} s"
                    ) from None
                time.sleep(0.01)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock
