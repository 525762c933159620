"""The one way the project writes a file (:mod:`ttc.atomic`): whole or not at all, into a
folder made when missing, readable by everyone whatever the umask."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from ttc.atomic import (
    atomic_write,
    remove_stale_temporaries,
    write_bytes_atomic,
    write_bytes_identified,
)


def test_a_file_is_written_into_a_folder_made_when_missing(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "record.json"
    assert write_bytes_atomic(b"{}", path) == path
    assert path.read_bytes() == b"{}" and os.listdir(path.parent) == ["record.json"]
    write_bytes_atomic(b"[1]", path)  # replaced whole, nothing left beside it
    assert path.read_bytes() == b"[1]" and os.listdir(path.parent) == ["record.json"]


def test_the_file_is_readable_by_everyone_whatever_the_umask(tmp_path: Path) -> None:
    before = os.umask(0o077)
    try:
        path = write_bytes_atomic(b"x", tmp_path / "f")
    finally:
        os.umask(before)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_a_failing_writer_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = write_bytes_atomic(b"old", tmp_path / "f")

    def fail(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(path, fail)
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["f"]
    assert remove_stale_temporaries(tmp_path) == 0


def test_bytes_written_through_the_descriptor_with_their_identity(tmp_path: Path) -> None:
    """Written whole (64 MiB, more than one write may take), mode 0644 under umask 077, and
    the stat returned is the file's as it lies (inode, size, mtime: the rename kept them);
    data that cannot be written leaves the old file and no temporary."""
    data = os.urandom(1 << 20) * 64
    before = os.umask(0o077)
    try:
        written = write_bytes_identified(data, tmp_path / "d" / "big.bin")
    finally:
        os.umask(before)
    path = tmp_path / "d" / "big.bin"
    now = path.stat()
    assert path.read_bytes() == data and stat.S_IMODE(now.st_mode) == 0o644
    assert (written.st_ino, written.st_size, written.st_mtime_ns) == (
        now.st_ino, now.st_size, now.st_mtime_ns)  # fmt: skip
    with pytest.raises(TypeError):
        write_bytes_identified("not bytes", path)  # type: ignore[arg-type]
    assert path.read_bytes() == data and os.listdir(path.parent) == ["big.bin"]
