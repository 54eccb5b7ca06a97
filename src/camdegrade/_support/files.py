"""Writing files atomically and durably. No camdegrade imports, so every layer may use it."""

from __future__ import annotations

import glob
import os
import re
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

#: Temporary files of our naming (``.NAME.<32 hex>.tmp``) older than this are left-overs of a killed writer: the
#: next write of NAME removes them. Younger ones may belong to a writer still at work and are left alone.
STALE_TEMPORARY_S = 15 * 60
#: Temporary names keep at most this many bytes of the target's name, so that ``.NAME.<32 hex>.tmp`` stays within
#: the usual 255-byte limit for a target name that is itself within it.
_KEPT_NAME_BYTES = 200


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; it is renamed onto ``path`` only if the block succeeds.

    Readers never see a half-written file, and a failure leaves any previous file at ``path`` untouched. The file
    is flushed to disk before the rename and the folder after it, so a power cut leaves the old file or the new
    one, never an empty one. Temporary files a killed writer left beside ``path`` are removed once stale.
    """
    path = Path(path)
    if path.is_dir():  # os.replace would fail only after the whole file was written, naming the temporary
        raise IsADirectoryError(f"cannot write {str(path)!r}: it is a folder")
    make_parent(path)
    _remove_stale_temporaries(path)
    # A fresh name rather than mkstemp: the writer creates the file, so it gets the usual umask permissions.
    temporary = _temporary_name(path)
    try:
        yield temporary
        os.chmod(temporary, 0o666 & ~_umask())  # some writers (safetensors) create files readable by owner only
        _fsync(temporary, os.O_RDONLY)
        os.replace(temporary, path)
        with suppress(OSError):  # some file systems cannot sync a folder; the rename itself is still atomic
            _fsync(path.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as error:
        # Failures on the temporary (no permission, read-only or full file system) are named by the target: the
        # temporary's name means nothing to the caller, and it is gone.
        if str(temporary) in (str(error.filename), str(error.filename2)):
            raise type(error)(f"cannot write {str(path)!r}: {error.strerror or error}") from error
        raise
    finally:
        temporary.unlink(missing_ok=True)


def make_parent(path: str | os.PathLike[str]) -> None:
    """Create ``path``'s folder (and its parents); a regular file in the way is named as such."""
    parent = Path(path).parent
    blocker = _file_in_the_way(parent)
    if blocker is not None:
        raise NotADirectoryError(f"cannot write {str(path)!r}: {str(blocker)!r} is a file, not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        reason = error.strerror or error
        raise type(error)(f"cannot write {str(path)!r}: cannot create folder {str(parent)!r}: {reason}") from error


def check_writable(path: str | os.PathLike[str]) -> None:
    """Raise ``OSError`` naming ``path`` unless a file can be written there, by creating (and removing) a temporary
    file in the nearest existing folder on its way. Nothing is left behind. For checks before long work."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"cannot write {str(path)!r}: it is a folder")
    blocker = _file_in_the_way(path.parent)
    if blocker is not None:
        raise NotADirectoryError(f"cannot write {str(path)!r}: {str(blocker)!r} is a file, not a folder")
    folder = next(ancestor for ancestor in [path.parent, *path.parent.parents] if ancestor.exists())
    probe = _temporary_name(folder / path.name)
    try:
        probe.open("xb").close()
    except OSError as error:
        raise type(error)(f"cannot write {str(path)!r}: {error.strerror or error}") from None
    probe.unlink(missing_ok=True)


def folder_relation(input_folder: str | os.PathLike[str], output_folder: str | os.PathLike[str]) -> str | None:
    """``"same"`` when the two folders are one (resolved), ``"inside"`` when the output lies within the input (a
    rerun would read what the first run wrote), else ``None``."""
    source, target = Path(input_folder).resolve(), Path(output_folder).resolve()
    if target == source:
        return "same"
    return "inside" if target.is_relative_to(source) else None


def check_outputs_spare_inputs(jobs: list[tuple[Path, Path]]) -> None:
    """Raise ``ValueError`` when the output of any ``(input, output)`` job is one of the inputs: the same resolved
    path, a hard link or a symbolic link to it. Checked before anything is written."""
    inputs = {}
    for source, _ in jobs:
        identity = _identity(source)
        if identity is not None:
            inputs[identity] = source
    for _, target in jobs:
        identity = _identity(target)
        if identity is not None and identity in inputs:
            raise ValueError(
                f"output {str(target)!r} is the input file itself ({str(inputs[identity])!r}); camdegrade never "
                "writes over a file it reads: choose another output"
            )


def same_file(first: Path, second: Path) -> bool:
    """Whether two paths name one file: the same path once resolved, or (when they exist) the same inode."""
    if Path(first).resolve() == Path(second).resolve():
        return True
    identity = _identity(Path(first))
    return identity is not None and identity == _identity(Path(second))


def _identity(path: Path) -> tuple[int, int] | None:
    try:
        status = path.stat()
    except OSError:
        return None
    return (status.st_dev, status.st_ino)


def _file_in_the_way(folder: Path) -> Path | None:
    """The first existing ancestor of ``folder`` (itself included) that is not a folder, if any."""
    for ancestor in [folder, *folder.parents]:
        if ancestor.exists() or ancestor.is_symlink():
            return None if ancestor.is_dir() else ancestor
    return None


def _temporary_name(path: Path) -> Path:
    return path.with_name(f".{_kept_name(path)}.{uuid.uuid4().hex}.tmp")


def _kept_name(path: Path) -> str:
    """At most :data:`_KEPT_NAME_BYTES` bytes of ``path``'s name. A name that is not valid UTF-8 arrives with
    surrogate escapes, which ``str.encode`` refuses: it is cut as the file system's bytes."""
    try:
        return path.name.encode()[:_KEPT_NAME_BYTES].decode(errors="ignore")
    except UnicodeEncodeError:
        return os.fsdecode(os.fsencode(path.name)[:_KEPT_NAME_BYTES])


def _remove_stale_temporaries(path: Path) -> None:
    name = _kept_name(path)
    ours = re.compile(rf"\.{re.escape(name)}\.[0-9a-f]{{32}}\.tmp")
    oldest = time.time() - STALE_TEMPORARY_S
    with suppress(OSError):
        for candidate in path.parent.glob(f".{glob.escape(name)}.*.tmp"):
            with suppress(OSError):
                if ours.fullmatch(candidate.name) and candidate.lstat().st_mtime < oldest:
                    candidate.unlink()


def _fsync(path: Path, flags: int) -> None:
    descriptor = os.open(path, flags)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _umask() -> int:
    """The process umask, read without changing it where the OS allows (os.umask alone must set it to read it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    current = os.umask(0o022)
    os.umask(current)
    return current
