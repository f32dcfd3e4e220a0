"""Build and load the compiled inference kernel (``transformer_step.c``) with the system C compiler.

The library is compiled on first use (~1 s) into a cache folder and loaded with ``ctypes``; later processes
load the cached file. Its name carries a hash of the source, the compiler's version, the flags, the machine
and the CPU's feature flags (the build uses ``-march=native``), so an edited source, another compiler or a
home folder shared by different CPUs gets its own build.

Environment:
    ``NAVFORMER_NATIVE=0``: never build or load it (every caller takes the torch path).
    ``CC``: the compiler command (default ``cc``).
    ``NAVFORMER_CACHE_DIR``: where the library goes (default ``$XDG_CACHE_HOME/navformer_rl`` or
    ``~/.cache/navformer_rl``; the system temp folder when that is not writable).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from navformer_rl.utils.durable import atomic_path

SOURCE = Path(__file__).with_name("transformer_step.c")
"""The kernel's C source (package data)."""
DISABLE_VARIABLE = "NAVFORMER_NATIVE"
CACHE_VARIABLE = "NAVFORMER_CACHE_DIR"
NATIVE_FLAGS = ("-O3", "-march=native", "-std=gnu11", "-fPIC", "-shared", "-fno-math-errno")
"""Tried first; ``PORTABLE_FLAGS`` when the compiler rejects ``-march=native``."""
PORTABLE_FLAGS = ("-O3", "-std=gnu11", "-fPIC", "-shared", "-fno-math-errno")
ABI_VERSION = 1
"""``navformer_step_abi()`` of a library whose structs match ``step.py``'s ctypes mirrors."""


class NativeBuildError(RuntimeError):
    """The kernel could not be compiled or loaded (the message says why and how to fix or disable it)."""


@dataclass(frozen=True)
class NativeStatus:
    """Whether the compiled kernel can be used in this process.

    library: the loaded library (None when unavailable); reason: why not (or the library's path).
    """

    library: ctypes.CDLL | None
    reason: str

    @property
    def available(self) -> bool:
        return self.library is not None


def native_status() -> NativeStatus:
    """The kernel for this process: built or found in the cache on the first call, then reused.

    ``NAVFORMER_NATIVE=0`` makes it unavailable (checked at every call). Never raises: a missing compiler or a
    failed build is reported in ``reason``.
    """
    if os.environ.get(DISABLE_VARIABLE, "").strip() == "0":
        return NativeStatus(None, f"disabled by {DISABLE_VARIABLE}=0")
    return _cached_status()


@functools.cache
def _cached_status() -> NativeStatus:
    try:
        path = build_library()
        return NativeStatus(load_library(path), str(path))
    except NativeBuildError as error:
        return NativeStatus(None, str(error))


def default_cache_dir() -> Path:
    """``$NAVFORMER_CACHE_DIR``, else ``$XDG_CACHE_HOME/navformer_rl`` or ``~/.cache/navformer_rl``."""
    configured = os.environ.get(CACHE_VARIABLE)
    if configured:
        return Path(configured).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "navformer_rl"


def compiler_command() -> list[str]:
    """The C compiler command: ``$CC`` split like a shell would, else ``cc``."""
    return shlex.split(os.environ.get("CC", "cc")) or ["cc"]


def build_library(
    source: Path = SOURCE, cache_dir: Path | None = None, compiler: list[str] | None = None
) -> Path:
    """Path of the compiled ``source`` for this machine and compiler, compiling it if not cached yet.

    The library is written atomically (a temporary file renamed into place), so processes building at the
    same time, or one killed mid-build, never leave a partial file under the final name.

    Raises:
        NativeBuildError: no compiler on ``PATH``, or it failed on both flag sets (its message is included).
    """
    compiler = compiler or compiler_command()
    if shutil.which(compiler[0]) is None:
        raise NativeBuildError(
            f"no C compiler: {compiler[0]!r} is not on PATH (set CC to one, or {DISABLE_VARIABLE}=0 to use "
            "the torch path without trying)"
        )
    version = _run([*compiler, "--version"]).stdout
    target_dir = _writable(cache_dir or default_cache_dir())
    digest = hashlib.sha256()
    for part in (source.read_bytes(), version.encode(), repr(NATIVE_FLAGS + PORTABLE_FLAGS).encode(),
                 platform.machine().encode(), cpu_signature().encode()):  # fmt: skip
        digest.update(part)
    target = target_dir / f"navformer_step-{digest.hexdigest()[:16]}.so"
    if target.exists():
        return target
    errors = []
    for flags in (NATIVE_FLAGS, PORTABLE_FLAGS):
        command = [*compiler, *flags, "-o", "<output>", str(source)]
        try:
            with atomic_path(target) as tmp:  # renamed onto target only if the block returns normally
                command[-2] = str(tmp)
                result = _run(command)
                if result.returncode != 0:
                    raise _CompileFailed(result.stderr.strip()[-2000:])
            return target
        except _CompileFailed as failure:
            errors.append(f"{shlex.join(command)}:\n{failure}")
    raise NativeBuildError("compiling the transformer-step kernel failed:\n" + "\n".join(errors))


class _CompileFailed(Exception):
    """The compiler's stderr, raised inside ``atomic_path`` so that it removes the partial output."""


def _run(command: list[str]) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise NativeBuildError(f"running {shlex.join(command)} failed: {error}") from error


def _writable(folder: Path) -> Path:
    """``folder`` (created) if this process may write there, else a per-user folder in the temp dir."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if os.access(folder, os.W_OK):
            return folder
    except OSError:
        pass
    fallback = Path(tempfile.gettempdir()) / f"navformer_rl-{os.getuid()}"
    fallback.mkdir(parents=True, exist_ok=True)
    return fallback


def cpu_signature() -> str:
    """The CPU's model and feature flags (``/proc/cpuinfo`` on Linux, ``platform.processor()`` elsewhere)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor()
    wanted = ("model name", "flags", "Features", "CPU part")
    picked = {line.split(":")[0].strip(): line for line in lines if line.split(":")[0].strip() in wanted}
    return "\n".join(picked[key] for key in sorted(picked))


def load_library(path: Path) -> ctypes.CDLL:
    """Load a built kernel and check that its structs are the ones ``step.py`` mirrors.

    Raises:
        NativeBuildError: the file cannot be loaded or reports another ABI version.
    """
    try:
        library = ctypes.CDLL(str(path))
        library.navformer_step_abi.restype = ctypes.c_int64
        abi = library.navformer_step_abi()
    except (OSError, AttributeError) as error:
        raise NativeBuildError(f"loading {path} failed: {error} (delete it to rebuild)") from error
    if abi != ABI_VERSION:
        raise NativeBuildError(f"{path}: ABI version {abi}, expected {ABI_VERSION} (delete it to rebuild)")
    return library
