"""Drawing batches ahead in a background thread: the same batches, the state of those handed out."""

import threading

import pytest
import torch

from navformer_rl.data import CrossTaskReplayBuffer, open_dataset
from navformer_rl.data.prefetch import Prefetcher


class _Counter:
    """A sampler whose items are 0, 1, 2, ... and whose state is the next item."""

    def __init__(self, fail_at=None):
        self.next_item, self.fail_at = 0, fail_at
        self.threads: set[str] = set()

    def draw(self):
        self.threads.add(threading.current_thread().name)
        if self.next_item == self.fail_at:
            raise RuntimeError(f"draw {self.fail_at} failed")
        self.next_item += 1
        return self.next_item - 1

    def capture(self):
        return {"next": self.next_item}

    def restore(self, state):
        self.next_item = state["next"]


def _prefetcher(counter, enabled=True):
    return Prefetcher(counter.draw, counter.capture, counter.restore, enabled=enabled)


@pytest.mark.parametrize("enabled", [True, False])
def test_items_and_state_are_those_of_a_plain_loop(enabled):
    counter = _Counter()
    prefetcher = _prefetcher(counter, enabled)
    assert [prefetcher.next() for _ in range(5)] == [0, 1, 2, 3, 4]
    # item 5 is being drawn ahead (enabled), yet the state is the one after the 5 items handed out
    assert prefetcher.state_dict() == {"next": 5}
    prefetcher.close()
    assert counter.next_item == 5  # the item drawn ahead was given back
    assert any(name.startswith("navformer-prefetch") for name in counter.threads) is enabled
    assert prefetcher.next() == 5  # after close(): goes on where it stopped


def test_load_state_drops_the_item_drawn_ahead():
    counter = _Counter()
    prefetcher = _prefetcher(counter)
    assert [prefetcher.next() for _ in range(3)] == [0, 1, 2]
    saved = prefetcher.state_dict()
    assert [prefetcher.next() for _ in range(4)] == [3, 4, 5, 6]
    prefetcher.load_state_dict(saved)  # a resume: the batches after the checkpoint come again
    assert [prefetcher.next() for _ in range(2)] == [3, 4]
    assert prefetcher.next(draw_ahead=False) == 5
    assert counter.next_item == 6 and prefetcher.state_dict() == {"next": 6}  # nothing drawn past the end
    prefetcher.close()


def test_a_failed_draw_is_raised_by_the_next_call():
    prefetcher = _prefetcher(_Counter(fail_at=2))
    assert [prefetcher.next() for _ in range(2)] == [0, 1]  # item 2 fails in the background thread
    with pytest.raises(RuntimeError, match="draw 2 failed"):
        prefetcher.next()
    prefetcher.close()


def test_the_background_thread_keeps_the_training_threads():
    counter = _Counter()
    seen = []
    prefetcher = Prefetcher(lambda: seen.append(torch.get_num_threads()), counter.capture, counter.restore)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for _ in range(3):
            prefetcher.next()
        prefetcher.close()
        # the first draw runs in the caller; the three after it (one dropped by close) in the thread
        assert seen == [2, 1, 1, 1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)


def test_two_buffer_sets_keep_a_batch_while_the_next_is_drawn(e_dataset, ssl_dataset):
    e, ssl = open_dataset(e_dataset), open_dataset(ssl_dataset)
    for make in (
        lambda sets: e.trajectory_batcher(4, context_steps=40, seed=3, buffer_sets=sets),
        lambda sets: ssl.pair_batcher(8, seed=3, buffer_sets=sets),
    ):
        one, two = make(1), make(2)
        first_one, first_two = one.sample(), two.sample()
        kept_two = first_two.clone()
        second_one, second_two = one.sample(), two.sample()
        assert (first_two == kept_two).all()  # two sets: the first batch is intact
        assert (second_one == second_two).all()  # the same draws either way
        key = "pixels" if "pixels" in first_one.keys() else "pixels_static"
        assert first_one[key].data_ptr() == second_one[key].data_ptr()  # one set: the same memory
        assert first_two[key].data_ptr() != second_two[key].data_ptr()
        assert (two.sample()[key].data_ptr()) == first_two[key].data_ptr()  # the sets alternate


def test_bad_buffer_options_are_refused(e_dataset, monkeypatch):
    ds = open_dataset(e_dataset)
    with pytest.raises(ValueError, match="buffer_sets must be an integer >= 1, got 0"):
        ds.trajectory_batcher(4, buffer_sets=0)
    # pinned memory on a machine without CUDA (pretended, so that the check runs on any host)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="pin_memory=True needs CUDA"):
        ds.trajectory_batcher(4, pin_memory=True)


def test_prefetching_the_cross_task_batches_draws_the_same_ones(e_dataset, ca_dataset):
    def make(sets):
        e, ca = open_dataset(e_dataset), open_dataset(ca_dataset)
        sampler = CrossTaskReplayBuffer(
            e.trajectory_batcher(3, 30, seed=1, buffer_sets=sets),
            ca.trajectory_batcher(4, 30, seed=2, buffer_sets=sets),
        )
        return sampler, Prefetcher(
            lambda: (lambda batch: (sampler.task_of(batch), batch.clone()))(sampler.sample()),
            sampler.state_dict,
            sampler.load_state_dict,
            enabled=sets == 2,
        )

    _, plain = make(1)
    _, ahead = make(2)
    for _ in range(5):
        (task_a, a), (task_b, b) = plain.next(), ahead.next()
        assert task_a == task_b and (a == b).all()
    assert plain.state_dict()["iteration"] == ahead.state_dict()["iteration"] == 5
    ahead.close()
