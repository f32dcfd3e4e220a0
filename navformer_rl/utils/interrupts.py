"""Interrupts: Ctrl-C with process pools, SIGTERM as an interrupt, and interrupts deferred to a safe point.

Process pools: the workers stay quiet, the parent process reports the interruption once.

Ctrl-C sends SIGINT to every process of the terminal's process group. A ``spawn`` worker still importing
torch when it arrives prints a long ``KeyboardInterrupt`` traceback, and so does a worker interrupted
between tasks. :func:`spawn_context` starts workers with SIGINT blocked (a blocked signal stays blocked
across ``exec`` and waits, pending, until it is unblocked), which covers their start-up. A worker that
should stop at once on Ctrl-C calls :func:`exit_on_sigint` first thing in its initializer: from then on,
and for a Ctrl-C that came during its start-up, it ends silently; a worker that does not call it never
sees SIGINT (its parent stops it).

SIGTERM is raised as :class:`Terminated`, a ``KeyboardInterrupt``, so that the same clean-up runs. A loop
that must not stop half-way through a step (a training iteration) runs inside :func:`stop_at_safe_point`:
the first Ctrl-C or SIGTERM is only recorded, the loop finishes its step, saves what it needs and raises it
(:meth:`StopRequest.interrupt`); a second one interrupts at once.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
from collections.abc import Iterator
from multiprocessing.context import SpawnContext, SpawnProcess

_SIGINT = {signal.SIGINT}


class _SpawnProcessBlockingSigint(SpawnProcess):
    """A ``spawn`` process that starts with SIGINT blocked (blocked in the starting thread around ``start``;
    the parent's other threads still take a Ctrl-C meanwhile, else it waits until ``start`` returns)."""

    def start(self) -> None:
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGINT)
        try:
            super().start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _SpawnContextBlockingSigint(SpawnContext):
    Process = _SpawnProcessBlockingSigint


def spawn_context() -> multiprocessing.context.BaseContext:
    """The ``spawn`` multiprocessing context, with every process it starts blocking SIGINT (Ctrl-C is the
    parent's to handle); pass it as ``ProcessPoolExecutor(mp_context=...)``."""
    return _SpawnContextBlockingSigint()


def exit_on_sigint() -> None:
    """In a worker process of :func:`spawn_context`: from now on Ctrl-C ends this process at once and
    silently (exit status 130), and so does one that arrived while it started.

    The pool then reports its workers as gone and the parent, interrupted by the same Ctrl-C, stops waiting
    for them. Temporary files a task was writing stay behind, as after any killed process
    (:func:`navformer_rl.utils.durable.atomic_leftovers`)."""
    signal.signal(signal.SIGINT, _exit_now)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGINT)


def _exit_now(signum: int, frame: object) -> None:
    os._exit(128 + signum)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's ``KeyboardInterrupt`` so that the same clean-up runs (collector and
    process-pool shutdown, the one-line report); the ``navformer`` command exits with status 143."""


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """The exception a signal stands for: :class:`Terminated` for SIGTERM, ``KeyboardInterrupt`` otherwise."""
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


class StopRequest:
    """What :func:`stop_at_safe_point` recorded: ``signum`` (SIGINT or SIGTERM), None while none came."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def interrupt(self) -> KeyboardInterrupt:
        """The exception to raise at the safe point (:class:`Terminated` when no signal came to this process,
        as on the other ranks of a data-parallel run that one process's signal stops)."""
        return interrupt_for(self.signum if self.signum is not None else signal.SIGTERM)


@contextlib.contextmanager
def stop_at_safe_point() -> Iterator[StopRequest]:
    """Within the block, the first Ctrl-C or SIGTERM only sets the yielded :class:`StopRequest`; the block
    checks ``requested`` at its safe points and raises ``interrupt()``. A second signal raises at once. The
    previous handlers come back on exit. Outside the main thread (where Python cannot set handlers) the
    request never comes and signals keep their handlers."""
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return

    def record(signum: int, frame: object) -> None:
        if request.requested:
            raise interrupt_for(signum)
        request.signum = signum

    previous = {signum: signal.signal(signum, record) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield request
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
