"""The allocator setting: big freed blocks are reused (no fresh pages), and training applies it when asked."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from navformer_rl.utils import allocator

# A child process allocates, touches and frees a 64 MiB tensor six times and prints the minor page faults of
# the last five rounds: a block that size is above glibc's largest mmap threshold (32 MiB), so by default
# every round maps fresh pages (>= 32 faults even with 2 MiB huge pages); with keep_freed_memory() the
# rounds after the first reuse the heap's pages. The child runs with huge pages for malloc, as run.sh sets
# them (without, glibc's heap may grow past a freed block that small objects have split: see allocator.py).
_FAULTS = textwrap.dedent(
    """
    import resource, sys, torch
    from navformer_rl.utils.allocator import keep_freed_memory
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for round in range(6):
        if round == 1:
            start = faults()
        block = torch.empty(16 << 20, dtype=torch.float32)
        block.fill_(1.0)
        del block
    print(faults() - start)
    """
)


def _page_faults(mode: str) -> int:
    env = {**os.environ, "GLIBC_TUNABLES": "glibc.malloc.hugetlb=1"}
    out = subprocess.run(
        [sys.executable, "-c", _FAULTS, mode],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
        env=env,
    )
    return int(out.stdout.split()[-1])


@pytest.mark.slow  # page-fault counts depend on the machine's memory state (huge pages, other jobs' memory)
@pytest.mark.skipif(allocator._glibc() is None, reason="the setting exists for glibc only")
def test_keep_freed_memory_reuses_big_blocks_instead_of_mapping_fresh_pages():
    default, kept = _page_faults("default"), _page_faults("keep")
    assert default >= 5 * 32, default  # 5 rounds x 64 MiB in fresh pages of at most 2 MiB
    assert kept * 10 < default, (kept, default)  # the same 320 MiB from pages the process already has


# Two training steps of the paper encoder on 768 frames (its first activation, [768, 32, 20, 20] float32, is
# 39 MB: above the mmap threshold, so the two settings serve it from different memory), saved for comparison.
_TRAIN = textwrap.dedent(
    """
    import sys, torch
    from navformer_rl.utils.allocator import keep_freed_memory
    from navformer_rl.modules.models.cnn import ConvEncoder
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    torch.manual_seed(0)
    torch.set_num_threads(1)
    encoder = ConvEncoder(channels_last=False, space_to_depth=False)
    optimizer = torch.optim.AdamW(encoder.parameters(), lr=1e-3)
    pixels = torch.randint(0, 256, (768, 84, 84, 3), dtype=torch.uint8)
    for _ in range(2):
        optimizer.zero_grad()
        encoder(pixels).square().mean().backward()
        optimizer.step()
    torch.save(encoder.state_dict(), sys.argv[2])
    """
)


@pytest.mark.skipif(allocator._glibc() is None, reason="the setting exists for glibc only")
def test_keep_freed_memory_gives_the_same_training_values(tmp_path):
    import torch

    weights = {}
    for mode in ("default", "keep"):
        path = tmp_path / f"{mode}.pt"
        subprocess.run([sys.executable, "-c", _TRAIN, mode, str(path)], check=True, timeout=300)
        weights[mode] = torch.load(path, weights_only=True)
    assert weights["default"].keys() == weights["keep"].keys()
    assert all(torch.equal(weights["default"][k], weights["keep"][k]) for k in weights["default"])


# keep_freed_memory, then 256 MiB of tensors allocated, touched and freed: the heap keeps their pages until
# release_free_memory hands them back. Prints the resident MiB after the free and after the release.
_RELEASE = textwrap.dedent(
    """
    import torch
    from navformer_rl.utils.allocator import keep_freed_memory, release_free_memory
    def resident_mib():
        return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
    assert keep_freed_memory()
    blocks = [torch.ones(16 << 20) for _ in range(4)]
    del blocks
    kept = resident_mib()
    assert release_free_memory()
    print(kept, resident_mib())
    """
)


@pytest.mark.skipif(allocator._glibc() is None, reason="the setting exists for glibc only")
def test_release_free_memory_hands_the_kept_pages_back():
    out = subprocess.run(
        [sys.executable, "-c", _RELEASE], capture_output=True, text=True, check=True, timeout=120
    )
    kept, released = map(float, out.stdout.split()[-2:])
    assert kept - released > 200, (kept, released)  # most of the 256 MiB
