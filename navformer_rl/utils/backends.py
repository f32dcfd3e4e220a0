"""Where work units run: a local process pool (the default) or Ray tasks, behind one small interface.

A work unit is ``fn(*args)`` with picklable arguments, submitted under a tag (any object the caller wants
back). :meth:`Backend.submit` starts one, :meth:`Backend.next_done` waits for any to finish and returns
``(tag, result)``, raising the unit's own error, and leaving the backend's ``with`` block on an error or a
Ctrl-C cancels the units not started and, on a Ctrl-C, stops the running ones too, so that no unit runs on
once the caller has returned. :func:`run_units` keeps :attr:`Backend.slots` units in flight over an
iterable of units and yields the results as they complete.

- ``local``: :class:`LocalPool`, a ``spawn`` process pool on this machine (:class:`InProcess` for one
  worker: the units run in this process, one at a time). The workers share this machine's files, so a
  unit may write its own results.
- ``ray``: :class:`RayTasks`, each unit a Ray task with ``num_cpus=1``, on an existing cluster
  (``address``, else ``$RAY_ADDRESS``: ``auto``, ``ray://host:10001``, ...) or on a local Ray instance
  with ``num_cpus=workers``; a Ray session already initialised in this process is used as it is. Tasks may
  run on other machines (:attr:`Backend.remote`), so a unit returns its results and the caller writes them.
  :meth:`RayTasks.close` shuts down a local instance it started and disconnects from a cluster it joined
  (the cluster keeps running).

``ray`` is an optional extra, imported only for the ``ray`` backend; without it :func:`check_backend`
raises ``ValueError`` with :data:`RAY_MISSING`.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import socket
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

BACKENDS: tuple[str, ...] = ("local", "ray")
"""The backend names: ``local`` (default) and ``ray``."""
RAY_MISSING = 'ray is not installed: pip install "navformer_rl[distributed]"'
"""The error message of ``backend="ray"`` without the ``distributed`` extra."""


def check_backend(backend: str) -> str:
    """``backend`` if it names a backend that can run here; ValueError naming it and the choices otherwise,
    or saying how to install ray for ``ray``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    if backend == "ray":
        _import_ray()
    return backend


def cluster_address(address: str | None = None) -> str | None:
    """The cluster a ``ray`` backend joins: ``address``, else ``$RAY_ADDRESS``, else None (a local one)."""
    return address or os.environ.get("RAY_ADDRESS") or None


def add_backend_options(parser: argparse.ArgumentParser, units: str) -> None:
    """Add ``--backend`` and ``--ray-address`` to a command line parser; ``units`` names its work units."""
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help=f"where the {units} run: local (default: worker processes here) or ray (Ray tasks)",
    )
    parser.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDRESS",
        help="with --backend ray: the cluster to join (auto, ray://HOST:10001, HOST:6379; default "
        "$RAY_ADDRESS, else a local Ray instance with --workers CPUs)",
    )


def backend_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with parsed ``--backend`` / ``--ray-address`` (ray not installed, an address without
    ray), or None."""
    if args.ray_address is not None and args.backend != "ray":
        return "--ray-address applies to --backend ray"
    try:
        check_backend(args.backend)
    except ValueError as error:
        return str(error)
    return None


class Backend(ABC):
    """Runs work units ``fn(*args)``; see the module docstring. Use it as a context manager."""

    remote: bool = False
    """Whether units may run on another machine (they must return their results, not write them)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.slots = 2 * workers
        """How many units to keep in flight: two per worker, so none waits for its next unit."""

    @abstractmethod
    def submit(self, tag: Any, fn: Callable[..., Any], /, *args: Any) -> None:
        """Start ``fn(*args)``; :meth:`next_done` returns its result with ``tag``."""

    @property
    @abstractmethod
    def in_flight(self) -> int:
        """Units submitted whose result :meth:`next_done` has not returned yet."""

    @abstractmethod
    def next_done(self) -> tuple[Any, Any]:
        """Wait for a unit in flight to finish: ``(tag, result)``, or the unit's error raised here."""

    @abstractmethod
    def cancel(self, interrupted: bool) -> None:
        """Drop the units not started; ``interrupted`` (Ctrl-C): stop the running ones now too."""

    @abstractmethod
    def close(self) -> None:
        """Release the workers (waiting for units still running)."""

    def __enter__(self) -> Backend:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        try:
            if exc_type is not None:
                self.cancel(interrupted=issubclass(exc_type, KeyboardInterrupt))
        finally:
            self.close()


def run_units(
    backend: Backend, fn: Callable[..., Any], units: Iterable[tuple[Any, tuple]]
) -> Iterator[tuple[Any, Any]]:
    """``fn(*args)`` for each ``(tag, args)`` of ``units`` on ``backend``, at most ``backend.slots`` at a
    time (``units`` is read as slots free up); yields ``(tag, result)`` in the order they complete."""
    todo = iter(units)
    exhausted = False
    while True:
        while not exhausted and backend.in_flight < backend.slots:
            unit = next(todo, None)
            if unit is None:
                exhausted = True
            else:
                backend.submit(unit[0], fn, *unit[1])
        if backend.in_flight == 0:
            return
        yield backend.next_done()


def open_backend(
    backend: str,
    workers: int,
    *,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
    address: str | None = None,
) -> Backend:
    """The ``backend`` (:data:`BACKENDS`) with ``workers`` workers.

    ``local``: :class:`InProcess` for one worker, else :class:`LocalPool` whose processes run
    ``initializer(*initargs)`` first. ``ray``: :class:`RayTasks` (``initializer`` is not run there: a Ray
    worker is not a child of this process and serves other callers too) joining ``address``
    (:func:`cluster_address`) or starting a local instance.
    """
    check_backend(backend)
    if backend == "ray":
        return RayTasks(workers, address)
    if workers == 1:
        return InProcess()
    return LocalPool(workers, initializer, initargs)


@contextlib.contextmanager
def session(backend: str, workers: int, address: str | None = None) -> Iterator[None]:
    """For ``ray``: one Ray session around several calls (joined or started here as in :class:`RayTasks`,
    which then use it as it is), closed at the end; for ``local``: nothing."""
    check_backend(backend)
    if backend != "ray":
        yield
        return
    owned = _start_ray(workers, address)
    try:
        yield
    finally:
        if owned:
            _import_ray().shutdown()


class InProcess(Backend):
    """One worker, this process: :meth:`submit` runs the unit at once (its error is raised there)."""

    def __init__(self) -> None:
        super().__init__(1)
        self.slots = 1
        self._done: list[tuple[Any, Any]] = []

    def submit(self, tag: Any, fn: Callable[..., Any], /, *args: Any) -> None:
        self._done.append((tag, fn(*args)))

    @property
    def in_flight(self) -> int:
        return len(self._done)

    def next_done(self) -> tuple[Any, Any]:
        return self._done.pop(0)

    def cancel(self, interrupted: bool) -> None:
        self._done.clear()

    def close(self) -> None:
        pass


class LocalPool(Backend):
    """A ``spawn`` process pool of ``workers`` processes (SIGINT blocked while they start:
    :func:`~navformer_rl.utils.interrupts.spawn_context`), each running ``initializer(*initargs)`` first."""

    def __init__(
        self, workers: int, initializer: Callable[..., None] | None = None, initargs: tuple = ()
    ) -> None:
        from navformer_rl.utils.interrupts import spawn_context

        super().__init__(workers)
        self._pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=spawn_context(), initializer=initializer, initargs=initargs
        )
        self._pending: dict[Future, Any] = {}

    def submit(self, tag: Any, fn: Callable[..., Any], /, *args: Any) -> None:
        self._pending[self._pool.submit(fn, *args)] = tag

    @property
    def in_flight(self) -> int:
        return len(self._pending)

    def next_done(self) -> tuple[Any, Any]:
        finished, _ = wait(list(self._pending), return_when=FIRST_COMPLETED)
        future = next(iter(finished))
        return self._pending.pop(future), future.result()

    def cancel(self, interrupted: bool) -> None:
        for future in self._pending:
            future.cancel()
        self._pending.clear()
        if interrupted:  # units in flight are lost anyway: stop their workers instead of waiting for them
            for process in list((getattr(self._pool, "_processes", None) or {}).values()):
                process.terminate()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class RayTasks(Backend):
    """Each unit a Ray task (``num_cpus=1``): on the cluster at ``address`` (:func:`cluster_address`), or on a
    local Ray instance with ``num_cpus=workers`` (no dashboard), or in the Ray session already initialised
    in this process. :meth:`cancel` force-cancels the tasks in flight (their workers may be killed: units
    on this backend write nothing themselves); :meth:`close` shuts down a local instance started here and
    disconnects from a cluster joined here."""

    remote = True

    def __init__(self, workers: int, address: str | None = None) -> None:
        super().__init__(workers)
        self._ray = _import_ray()
        self._owned = _start_ray(workers, address)
        self._remote: dict[Callable[..., Any], Any] = {}
        self._pending: dict[Any, Any] = {}  # ObjectRef -> tag

    def submit(self, tag: Any, fn: Callable[..., Any], /, *args: Any) -> None:
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(num_cpus=1)(fn)
        self._pending[self._remote[fn].remote(*args)] = tag

    @property
    def in_flight(self) -> int:
        return len(self._pending)

    def next_done(self) -> tuple[Any, Any]:
        ready, _ = self._ray.wait(list(self._pending), num_returns=1)
        tag = self._pending.pop(ready[0])
        try:
            return tag, self._ray.get(ready[0])
        except self._ray.exceptions.RayTaskError as error:
            cause = getattr(error, "cause", None)
            if isinstance(cause, Exception) and not isinstance(cause, self._ray.exceptions.RayError):
                raise cause from error  # the unit's own error, as the process pool raises it
            raise

    def cancel(self, interrupted: bool) -> None:
        for ref in self._pending:
            with contextlib.suppress(Exception):  # finished meanwhile, or the connection is gone
                self._ray.cancel(ref, force=True)
        self._pending.clear()

    def close(self) -> None:
        if self._owned:
            self._owned = False
            self._ray.shutdown()


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ValueError(RAY_MISSING) from None
    return ray


def _start_ray(workers: int, address: str | None) -> bool:
    """Initialise Ray unless it already is: join :func:`cluster_address` or start a local instance with
    ``num_cpus=workers``; returns whether this call initialised it (its caller then shuts it down)."""
    ray = _import_ray()
    if ray.is_initialized():
        return False
    address = cluster_address(address)
    if address is not None:
        _check_reachable(address)
        try:
            ray.init(address=address, logging_level=logging.WARNING)
        except ConnectionError as error:  # e.g. "auto" without a cluster on this machine
            raise ValueError(f"ray address {address!r}: {error}") from None
    else:  # "local": a new instance, even beside a cluster started on this machine with `ray start`
        ray.init(address="local", num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING)
    return True


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """ValueError when ``address`` is ``[ray://]HOST:PORT`` and nothing answers there (``ray.init`` would
    retry for minutes); other forms (``auto``) are left to Ray."""
    host, colon, port = address.removeprefix("ray://").rpartition(":")
    if not (host and colon and port.isdigit()):
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as error:
        raise ValueError(
            f"ray address {address!r}: nothing answers at {host}:{port} ({error.strerror or error}); "
            "start the cluster (`ray start --head`) or give its address"
        ) from None
