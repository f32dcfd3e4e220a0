"""Durable writes: atomic file replacement, fsync helpers and folder locks (checkpoints, dataset shards,
evaluation outputs)."""

from __future__ import annotations

import errno
import fcntl
import os
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

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


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (same suffix); on success it is fsynced and renamed onto
    ``path`` (the folder fsynced too), so the file is complete whenever it exists, even after a power loss.

    For writers that want a file name (matplotlib, OpenCV, ffmpeg). On error the temporary file is removed and
    ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
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
