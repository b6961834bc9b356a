"""phri.atomic.write_atomic: whole files or nothing, written-once files never overwritten."""

from __future__ import annotations

from pathlib import Path

import pytest

from phri.atomic import partial_path, write_atomic


def test_write_atomic_replaces_whole_files_and_leaves_no_partial(tmp_path: Path) -> None:
    path = tmp_path / "a.csv"
    assert write_atomic(path, b"one\n") == path
    write_atomic(path, b"two\n")
    assert path.read_bytes() == b"two\n"
    assert not partial_path(path).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]


def test_write_atomic_never_overwrites_a_written_once_file(tmp_path: Path) -> None:
    path = tmp_path / "log.npz"
    write_atomic(path, b"first", overwrite=False)
    with pytest.raises(FileExistsError, match="never overwrites"):
        write_atomic(path, b"second", overwrite=False)
    assert path.read_bytes() == b"first"


def test_a_failed_write_keeps_the_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    path = tmp_path / "study.json"
    write_atomic(path, b"old")

    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_atomic(path, b"new")
    assert path.read_bytes() == b"old"
    assert not partial_path(path).exists()


def test_a_written_once_file_that_appears_during_the_write_is_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import os

    path = tmp_path / "log.npz"
    real_fsync = os.fsync

    def fsync_then_another_writer(fd: int) -> None:  # another process creates `path` meanwhile
        real_fsync(fd)
        if not path.exists():
            path.write_bytes(b"theirs")

    monkeypatch.setattr(os, "fsync", fsync_then_another_writer)
    with pytest.raises(FileExistsError, match="never overwrites"):
        write_atomic(path, b"mine", overwrite=False)
    assert path.read_bytes() == b"theirs"
    assert not partial_path(path).exists()


def test_without_hard_links_a_written_once_file_is_still_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno
    import os

    def no_links(src: object, dst: object) -> None:
        raise OSError(errno.EPERM, "hard links not supported")

    monkeypatch.setattr(os, "link", no_links)
    path = write_atomic(tmp_path / "log.npz", b"data", overwrite=False)
    assert path.read_bytes() == b"data"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.npz"]
