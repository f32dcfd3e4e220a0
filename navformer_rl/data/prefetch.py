"""Draw the next training batch in a background thread while the current one trains.

:class:`Prefetcher` wraps any ``draw()`` (here: the cross-task trajectory batch and the D_ssl pairs of one
iteration) and hands out exactly the items that calling ``draw()`` in a loop would, in the same order, one
call ahead: while iteration i runs forward and backward, iteration i + 1's frames are gathered from the
memmaps (``index_select`` releases the GIL). Its ``state_dict()`` is the samplers' state after the items
handed out so far - not after the one drawn ahead - so a checkpoint taken between iterations resumes on the
batch an uninterrupted run would draw next.

The batchers reuse their buffers, so a prefetching caller needs two buffer sets per batcher
(``buffer_sets=2`` of :class:`~navformer_rl.data.samplers.TrajectoryBatcher` / ``PairBatcher``): the batch
being trained on and the one being drawn. A handed-out item is valid until the next-but-one ``next()``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Generic, TypeVar

import torch

Item = TypeVar("Item")


class Prefetcher(Generic[Item]):
    """``next()`` returns ``draw()``'s items in order, computing each one call ahead in one background thread.

    Args:
        draw: makes the next item (it advances the samplers ``capture`` / ``restore`` describe).
        capture: returns a snapshot of the samplers' state (a fresh object: later draws must not change it).
        restore: loads such a snapshot back.
        enabled: False draws synchronously in ``next()`` (no thread), the same items.
        threads: torch intra-op threads of the background thread (its gathers); 1 leaves the cores to
            the training step.
    """

    def __init__(
        self,
        draw: Callable[[], Item],
        capture: Callable[[], Any],
        restore: Callable[[Any], None],
        *,
        enabled: bool = True,
        threads: int = 1,
    ) -> None:
        self.draw, self.capture, self.restore = draw, capture, restore
        self.enabled = bool(enabled)
        self.threads = int(threads)
        self._executor: ThreadPoolExecutor | None = None
        self._pending: Future | None = None
        self._state_before_pending: Any = None

    def next(self, draw_ahead: bool = True) -> Item:
        """The next item (drawn ahead in the background when enabled); then starts drawing the one after it,
        unless ``draw_ahead`` is False (the last iteration: nothing would use it)."""
        if not self.enabled:
            return self.draw()
        if self._pending is None:
            item = self.draw()
        else:
            pending, self._pending = self._pending, None
            item = pending.result()  # a draw's exception surfaces here, in the training loop
        if draw_ahead:
            self._state_before_pending = self.capture()
            self._pending = self._pool().submit(self.draw)
        return item

    def state_dict(self) -> Any:
        """The samplers' state after the items handed out so far (what a resumed run must start from)."""
        return self.capture() if self._pending is None else self._state_before_pending

    def load_state_dict(self, state: Any) -> None:
        """Drop the item drawn ahead and restore ``state``; the next ``next()`` draws from it."""
        self._drop_pending()
        self.restore(state)

    def close(self) -> None:
        """Wait for the draw in flight, drop it and stop the thread (``next()`` starts a new one)."""
        self._drop_pending()
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None

    def _drop_pending(self) -> None:
        if self._pending is None:
            return
        pending, self._pending = self._pending, None
        pending.exception()  # wait: the draw writes into the samplers and the buffers
        self.restore(self._state_before_pending)

    def _pool(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(
                max_workers=1,
                thread_name_prefix="navformer-prefetch",
                initializer=torch.set_num_threads,  # per thread: the training threads keep their count
                initargs=(self.threads,),
            )
        return self._executor
