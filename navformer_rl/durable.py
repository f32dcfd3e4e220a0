"""Durable writes: atomic file replacement and fsync helpers (checkpoints, dataset shards, evaluation outputs)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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
