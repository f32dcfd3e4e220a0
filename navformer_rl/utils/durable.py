"""Durable writes: atomic file replacement, fsync helpers and folder locks (checkpoints, dataset shards,
evaluation outputs)."""

from __future__ import annotations

import errno
import fcntl
import glob
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

_UMASK = os.umask(0)
os.umask(_UMASK)


def file_mode() -> int:
    """Mode of a file created with ``open`` under the process umask (0644 with umask 022); ``mkstemp``
    alone would leave a file owner-only (0600)."""
    return 0o666 & ~_UMASK


def dir_mode() -> int:
    """Mode of a folder created with ``mkdir`` under the process umask (0755 with umask 022; ``mkdtemp``
    creates 0700)."""
    return 0o777 & ~_UMASK


_MKSTEMP_RANDOM_CHARS = 8
"""Length of the random part of ``tempfile.mkstemp``'s names."""


def _temporary_affixes(path: Path) -> tuple[str, str]:
    """Prefix and suffix of the names :func:`atomic_path` gives its temporary files for ``path``:
    ``.<stem>.<mkstemp's random characters>.tmp<suffix>``."""
    return f".{path.stem}.", f".tmp{path.suffix}"


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (same suffix); on success it is fsynced and renamed onto
    ``path`` (the folder fsynced too), so the file is complete whenever it exists, even after a power loss.

    For writers that want a file name (matplotlib, OpenCV, ffmpeg). On error the temporary file is removed and
    ``path`` is left untouched; a process killed meanwhile leaves it (see :func:`atomic_leftovers`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    prefix, suffix = _temporary_affixes(path)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, file_mode())  # mkstemp creates 0600; give the file the usual permissions
    try:
        yield Path(tmp)
        fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically and durably (file and folder fsynced)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)


def atomic_write_json(path: str | os.PathLike, payload: Any) -> None:
    """Write ``payload`` to ``path`` as JSON (sorted keys, 2-space indent, final newline), atomically and
    durably (:func:`atomic_write_text`). Keep this format: dataset ``metadata.json`` and ``stats.json`` files
    have always been written in it, and the same content must give the same bytes."""
    atomic_write_text(path, json.dumps(payload, indent=2, sort_keys=True) + "\n")


def atomic_leftovers(path: str | os.PathLike) -> list[Path]:
    """The temporary files next to ``path`` that :func:`atomic_path` calls for ``path`` left when their
    process was killed before the rename (never committed data). Delete them only while no other process
    writes ``path``, e.g. under :func:`folder_lock`."""
    path = Path(path)
    prefix, suffix = _temporary_affixes(path)
    pattern = f"{glob.escape(prefix)}*{glob.escape(suffix)}"
    return sorted(
        candidate
        for candidate in path.parent.glob(pattern)
        if len(candidate.name) == len(prefix) + _MKSTEMP_RANDOM_CHARS + len(suffix) and candidate.is_file()
    )


def fsync_file(path: str | os.PathLike) -> None:
    """Flush ``path``'s data (memmapped files included) to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path: str | os.PathLike) -> None:
    """fsync the directory ``path`` so that renames and new entries in it survive a power loss."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(root: str | os.PathLike) -> None:
    """fsync every file under ``root``, then every directory, deepest first (one ``fsync`` each)."""
    dirs = []
    for folder, _, files in os.walk(root):
        dirs.append(folder)
        for name in files:
            fsync_file(os.path.join(folder, name))
    for folder in reversed(dirs):
        fsync_dir(Path(folder))


class FolderLockedError(RuntimeError):
    """Another live process is writing into the same folder (a collection, an evaluation)."""


def publish_folder(tmp: str | os.PathLike, final: str | os.PathLike) -> Path:
    """Make the finished temporary folder ``tmp`` (a sibling of ``final``) appear as ``final`` in one rename.

    Its files get :func:`file_mode` (``mkstemp`` / safetensors create them owner-only) and are flushed, the
    folder gets :func:`dir_mode` (``mkdtemp`` creates 0700); an existing ``final`` is moved aside first, so
    the rename cannot fail on a non-empty target, and removed after. A crash leaves ``final`` old or new,
    never half written. Returns ``final``."""
    tmp, final = Path(tmp), Path(final)
    for child in tmp.iterdir():
        os.chmod(child, file_mode())
        fsync_file(child)
    os.chmod(tmp, dir_mode())
    if final.exists():
        stale = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent))
        os.replace(final, stale / final.name)
        os.replace(tmp, final)
        shutil.rmtree(stale, ignore_errors=True)
    else:
        os.replace(tmp, final)
    fsync_dir(final.parent)
    return final


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextmanager
def folder_lock(root: str | os.PathLike, lock_name: str, activity: str) -> Iterator[Path]:
    """Hold ``root/<lock_name>`` (created, with this process's pid) while writing into ``root``.

    The lock is an exclusive ``flock`` on that file, so the kernel releases it when its holder dies: a lock
    file left by a killed process (its pid no longer holds the lock) is taken over with a warning. Raises
    :class:`FolderLockedError` naming the holder's pid when another live process holds ``root`` ("``root``
    is being ``activity`` by another process"). The file is removed on exit. Yields the lock file's path.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    path = root / lock_name
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            os.close(fd)
            if err.errno not in (errno.EAGAIN, errno.EACCES):
                raise
            holder = _read_pid(path)
            raise FolderLockedError(
                f"{root} is being {activity} by another process (pid {holder}, lock {path}); "
                "wait for it to finish or stop it, or use another folder"
            ) from None
        if os.path.exists(path) and os.stat(path).st_ino == os.fstat(fd).st_ino:
            break  # locked the file that is still in place (not one its previous holder just removed)
        os.close(fd)
    try:
        stale = _read_pid(path)
        if stale is not None and stale != os.getpid():
            alive = " (that pid is now another process)" if _pid_alive(stale) else ""
            warnings.warn(
                f"{root}: taking over the lock left by process {stale}, which no longer holds it{alive}",
                stacklevel=3,
            )
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        os.fsync(fd)
        yield path
    finally:
        with suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)


def _read_pid(path: Path) -> int | None:
    """The pid written in a lock file, or ``None`` when it is missing, empty or unreadable."""
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None
