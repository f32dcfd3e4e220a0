"""Ctrl-C with process pools: the workers stay quiet, the parent process reports the interruption once.

Ctrl-C sends SIGINT to every process of the terminal's process group. A ``spawn`` worker still importing
torch when it arrives prints a long ``KeyboardInterrupt`` traceback, and so does a worker interrupted
between tasks. :func:`spawn_context` starts workers with SIGINT blocked (a blocked signal stays blocked
across ``exec`` and waits, pending, until it is unblocked), which covers their start-up. A worker that
should stop at once on Ctrl-C calls :func:`exit_on_sigint` first thing in its initializer: from then on,
and for a Ctrl-C that came during its start-up, it ends silently; a worker that does not call it never
sees SIGINT (its parent stops it).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
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
