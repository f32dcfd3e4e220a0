"""The process's C allocator: keep freed big blocks for reuse instead of returning them to the kernel.

glibc's ``malloc`` serves every block above its mmap threshold (at most 32 MiB) with a fresh ``mmap`` and
gives it back with ``munmap`` when freed. A CPU training iteration allocates and frees dozens of such
tensors (the GPT's ``[37950, 512]`` MLP activations and their gradients, the attention weights, ...), so
the kernel maps and zeroes those pages again at every iteration: with
``GLIBC_TUNABLES=glibc.malloc.hugetlb=1`` (transparent huge pages, what ``run.sh`` sets) a paper batch-B
iteration took ~6,000 page faults, ~750 of them 2 MiB huge pages. :func:`keep_freed_memory` switches that off
for the rest of the process (``mallopt(M_MMAP_MAX, 0)``: big blocks come from the heap too, and
``mallopt(M_TRIM_THRESHOLD, 2 GiB - 1)``: freed memory stays in the heap), so once the heap has grown to the
run's peak (a few iterations) the process reuses its pages (2-40 faults per batch-B iteration). On the 2-core
CPU a mean paper iteration then takes 0.80-0.88x the time, 0.88-0.95x in the real loop with its data sampling
(``benchmarks/model.md``, "Allocator: keep freed memory"). The values computed do not change. The cost: the
process's resident memory stays at its peak instead of shrinking between iterations. Without huge pages for
malloc, glibc may still grow the heap past a freed block that small objects have split (seen in a synthetic
loop of equal-size tensors; not in training, which faulted 2-7 pages per batch-B iteration that way too).

:func:`release_free_memory` (``malloc_trim(0)``) hands the free pages inside the heap back to the kernel;
``navformer train`` calls it after every checkpoint when it keeps freed memory, so what the heap's
fragmentation adds to the resident memory is undone once per checkpoint interval. Measured in the real loop
at the paper's batches: 4.3 GiB resident after 10 iterations, 5.1 GiB after 160, still growing ~2 MB per
iteration (glibc's default setting grew too: 3.9 GiB after 10 iterations, 4.6 GiB after 50); one
``malloc_trim`` took 16-33 ms and brought it to 1.6 GiB, and the next two iterations faulted their pages in
again (~2 s in all).

The same settings at process start: ``GLIBC_TUNABLES=glibc.malloc.hugetlb=1:glibc.malloc.mmap_max=0:
glibc.malloc.trim_threshold=2147483647``. Other C libraries (musl, macOS, Windows) are left alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_TRIM_THRESHOLD = -1
"""``mallopt`` parameter: free memory at the heap's top beyond this many bytes goes back to the kernel."""
M_MMAP_MAX = -4
"""``mallopt`` parameter: how many blocks may be served by ``mmap`` at once (0: none, all from the heap)."""
TRIM_THRESHOLD_BYTES = 2**31 - 1
"""The largest value ``mallopt`` takes (an ``int``): the heap is trimmed only past 2 GiB of free top."""


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The process's glibc, or None when the C library is another one."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        libc.gnu_get_libc_version  # noqa: B018 - only glibc has it
        libc.mallopt  # noqa: B018
    except (OSError, AttributeError):
        return None
    return libc


def keep_freed_memory() -> bool:
    """Make glibc's ``malloc`` serve big blocks from the heap and keep freed memory (see the module
    docstring).

    Returns True when the settings took effect, False on a C library other than glibc (nothing changes).
    Idempotent; there is no way back within the process.
    """
    libc = _glibc()
    if libc is None:
        return False
    mmap_ok = libc.mallopt(ctypes.c_int(M_MMAP_MAX), ctypes.c_int(0))
    trim_ok = libc.mallopt(ctypes.c_int(M_TRIM_THRESHOLD), ctypes.c_int(TRIM_THRESHOLD_BYTES))
    return bool(mmap_ok) and bool(trim_ok)


def release_free_memory() -> bool:
    """Return the free memory inside glibc's heap to the kernel (``malloc_trim(0)``); False elsewhere.

    The next iterations fault those pages in again, so call it rarely (``navformer train``: at checkpoints).
    """
    libc = _glibc()
    if libc is None:
        return False
    libc.malloc_trim(ctypes.c_size_t(0))
    return True
