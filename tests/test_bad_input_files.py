"""Atomic writes under crashes (issue 17): the file and its folder are flushed to disk around the rename, temporary
files a killed writer left behind are cleaned up once stale, and a path through a regular file is named."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

import pytest

import camdegrade._support.files as files
from camdegrade._support.files import atomic_path


def test_the_file_is_fsynced_before_the_rename_and_the_folder_after(tmp_path: Path, monkeypatch) -> None:
    events: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(source, target) -> None:
        events.append(("replace", str(target)))
        real_replace(source, target)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    target = tmp_path / "out.txt"
    with atomic_path(target) as temporary:
        temporary.write_text("data")
    kinds = [kind for kind, _ in events]
    assert kinds == ["fsync", "replace", "fsync"], events
    assert events[0][1].endswith(".tmp") and Path(events[0][1]).parent == tmp_path
    assert events[2][1] == str(tmp_path)
    assert target.read_text() == "data"


def _leftover(folder: Path, name: str, age_s: float) -> Path:
    """A temporary file as a killed writer leaves it: ``.NAME.<32 hex>.tmp``, ``age_s`` seconds old."""
    path = folder / f".{name}.{uuid.uuid4().hex}.tmp"
    path.write_text("half a file")
    stamp = time.time() - age_s
    os.utime(path, (stamp, stamp))
    return path


def test_stale_temporaries_of_our_naming_are_removed(tmp_path: Path) -> None:
    stale = _leftover(tmp_path, "profile.safetensors", files.STALE_TEMPORARY_S + 60)
    fresh = _leftover(tmp_path, "profile.safetensors", 5)  # another writer may still be at work
    other_target = _leftover(tmp_path, "other.safetensors", files.STALE_TEMPORARY_S + 60)
    not_ours = tmp_path / ".profile.safetensors.backup.tmp"
    not_ours.write_text("someone else's")
    os.utime(not_ours, (0, 0))
    with atomic_path(tmp_path / "profile.safetensors") as temporary:
        temporary.write_text("new")
    assert not stale.exists()
    assert fresh.exists() and other_target.exists() and not_ours.exists()
    assert (tmp_path / "profile.safetensors").read_text() == "new"


def test_a_failed_write_leaves_no_temporary_and_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "keep.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as temporary:
        temporary.write_text("half")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert [path.name for path in tmp_path.iterdir()] == ["keep.txt"]


def test_a_path_through_a_regular_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "file.png").write_bytes(b"x")
    target = tmp_path / "file.png" / "deeper" / "out.txt"
    with (
        pytest.raises(NotADirectoryError, match=r"'.*file\.png' is a file, not a folder"),
        atomic_path(target) as temporary,
    ):
        temporary.write_text("never")


def test_check_writable_creates_nothing(tmp_path: Path) -> None:
    files.check_writable(tmp_path / "sub" / "out.safetensors")
    files.check_writable(tmp_path / "out.safetensors")
    assert list(tmp_path.rglob("*")) == []
    with pytest.raises(OSError, match=r"cannot write '/proc/x\.safetensors'"):
        files.check_writable("/proc/x.safetensors")
