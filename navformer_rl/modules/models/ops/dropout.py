"""Dropout whose random mask is 3-4x cheaper to draw on CPU than ``torch.bernoulli_`` (same distribution).

On CPU, ``F.dropout`` draws one Bernoulli sample per element from the serial Mersenne-Twister at
~14 ns each, which made dropout the largest single cost of a NavFormer training iteration (the attention
weights alone are ``[150, 2, 252, 252]`` per block in the paper's batch B). ``keep_mask`` draws 64-bit
words with ``random_()`` over the full int64 range and compares their four uniform 16-bit lanes with a
threshold: one generator call per four elements. The keep probability is quantised to 1/65536 (p = 0.1 keeps
with probability 58982 / 65536 = 0.899994). Masks come from torch's default generator, so
``torch.manual_seed`` makes them reproducible and a checkpoint's saved RNG state resumes them exactly.
Other devices use ``F.dropout`` unchanged.

Large masks (``PARALLEL_WORDS`` words and more: the attention weights) are drawn in two halves by two
numpy ``SFC64`` generators in two threads, seeded from torch's default generator: torch's ``random_`` is
serial and two torch generators in two threads do not overlap, while numpy's fills release the GIL. The
halves are always two, whatever the thread count (one thread fills them one after the other), so a mask
depends only on the torch RNG state.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

PARALLEL_WORDS = 1 << 18  # masks of at least this many int64 words (1M elements) use two numpy generators


def keep_mask(shape: torch.Size | tuple[int, ...], keep_prob: float, device: torch.device | str) -> Tensor:
    """Bool ``shape`` tensor, each element True independently with probability ``keep_prob`` (to 1/65536)."""
    if not 0.0 <= keep_prob <= 1.0:
        raise ValueError(f"keep_prob={keep_prob!r}: expected a probability in [0, 1]")
    threshold = round(keep_prob * 65536) - 32768  # keep a lane in [-32768, 32767] iff it is below
    if threshold > 32767:
        return torch.ones(shape, dtype=torch.bool, device=device)
    numel = math.prod(shape)
    n_words = -(-numel // 4)
    if torch.device(device).type == "cpu" and n_words >= PARALLEL_WORDS:
        return _parallel_keep_mask(numel, threshold).view(shape)
    words = torch.empty(n_words, dtype=torch.int64, device=device).random_(-(2**63), None)
    lanes = words.view(torch.int16)[:numel]  # four uniform 16-bit lanes per 64-bit word
    return (lanes < threshold).view(shape)


def _parallel_keep_mask(numel: int, threshold: int) -> Tensor:
    """Flat bool ``[numel]``: two halves, each from a numpy ``SFC64`` seeded by torch's default generator."""
    seeds = torch.randint(0, 2**62, (2,), dtype=torch.int64).tolist()
    mask = torch.empty(numel, dtype=torch.bool)
    half = -(-numel // 8) * 4  # a whole number of words
    parts = [(seeds[0], mask[:half]), (seeds[1], mask[half:])]
    if torch.get_num_threads() > 1:
        futures = [_mask_pool().submit(_fill_mask, seed, part, threshold) for seed, part in parts]
        for future in futures:
            future.result()
    else:
        for seed, part in parts:
            _fill_mask(seed, part, threshold)
    return mask


def _fill_mask(seed: int, out: Tensor, threshold: int) -> None:
    """``out`` (bool ``[n]``) = four 16-bit lanes per ``SFC64(seed)`` word compared with ``threshold``."""
    words = np.random.SFC64(seed).random_raw(-(-out.numel() // 4))
    # numpy, not torch, compares: a torch op in a worker thread would start its own OpenMP team, whose
    # spinning threads then compete with the main thread's kernels
    np.less(words.view(np.int16)[: out.numel()], threshold, out=out.numpy())


_POOL: tuple[int, ThreadPoolExecutor] | None = None


def _mask_pool() -> ThreadPoolExecutor:
    """Two worker threads, made again in a forked child (threads do not survive a fork)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid():
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=2, thread_name_prefix="dropout-mask"))
    return _POOL[1]


def fast_dropout(x: Tensor, p: float, training: bool) -> Tensor:
    """``F.dropout(x, p, training)`` with ``keep_mask`` on CPU: zero with probability p,
    scale by 1 / (1 - p)."""
    if not training or p == 0.0:
        return x
    if x.device.type != "cpu":
        return F.dropout(x, p, training=True)
    mask = keep_mask(x.shape, 1.0 - p, x.device)
    return torch.where(mask, x, 0).mul_(1.0 / (1.0 - p))


class Dropout(nn.Dropout):
    """``nn.Dropout`` (same ``p``, repr and state dict) drawing its CPU masks with ``keep_mask``."""

    def __init__(self, p: float = 0.5) -> None:
        if not 0.0 <= p < 1.0:
            raise ValueError(f"Dropout: p={p!r}, expected a probability in [0, 1)")
        super().__init__(p)

    def forward(self, input: Tensor) -> Tensor:  # noqa: A002 - nn.Module's argument name
        return fast_dropout(input, self.p, self.training)
