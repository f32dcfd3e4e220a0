"""The compiled transformer-step kernel: the torch path's results, clear errors, a safe build and cache."""

import os
import shutil
import stat

import pytest
import torch

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel
from navformer_rl.modules.decoding.native import (
    BlockedKVCache,
    NativeBuildError,
    NativeTransformerStep,
    build,
    native_status,
    native_support,
)
from navformer_rl.modules.decoding.transformer_step import TransformerStep
from navformer_rl.modules.models.gpt import GPT2Blocks, KVCache

requires_native = pytest.mark.skipif(not native_status().available, reason=native_status().reason)


def test_the_kernel_builds_wherever_a_c_compiler_is_installed():
    """CI runs the native tests for real: with a compiler on PATH the kernel must build and load."""
    if shutil.which(build.compiler_command()[0]) is None:
        pytest.skip("no C compiler on PATH")
    if os.environ.get(build.DISABLE_VARIABLE) == "0":
        pytest.skip(f"{build.DISABLE_VARIABLE}=0")
    status = native_status()
    assert status.available, status.reason


def transformer(d, heads, d_head, mlp_ratio, gelu, seed=0):
    torch.manual_seed(seed)
    model = GPT2Blocks(d, n_blocks=2, n_heads=heads, d_head=d_head, mlp_ratio=mlp_ratio, dropout=0.0)
    for block in model.blocks:
        block.mlp[1].approximate = gelu
    return model.eval()


SHAPES = {
    # d, heads, d_head, mlp_ratio, GELU, batch, new tokens, slots
    "paper-widths": (128, 2, 64, 4, "none", 1, 4, 37),
    "column-and-query-tails": (48, 3, 32, 4, "tanh", 2, 5, 21),  # 3 H dh = 288, L = 5, dh = 32
    "three-tokens": (64, 1, 16, 2, "none", 3, 3, 16),  # the DT baseline's 3 tokens per step
}


@requires_native
@pytest.mark.parametrize("name", list(SHAPES))
def test_native_step_equals_the_torch_step_and_writes_the_same_cache(name):
    d, heads, d_head, mlp_ratio, gelu, batch, length, slots = SHAPES[name]
    model = transformer(d, heads, d_head, mlp_ratio, gelu)
    torch_step, native_step = TransformerStep(model), NativeTransformerStep(model)
    gen = torch.Generator().manual_seed(1)
    shape = (2, batch, heads, slots, d_head)
    reference = KVCache(list(torch.randn(shape, generator=gen)), list(torch.randn(shape, generator=gen)))
    blocked = BlockedKVCache.from_kv_cache(reference)
    calls = [  # (slots attended, where the new tokens go, mask shared by the batch or per sequence)
        (length, slice(0, length), "shared"),
        (slots - 3, torch.randperm(slots - 3, generator=gen)[: batch * length].view(batch, length), "per"),
        (slots, slice(slots - length, slots), "per"),
        (slots, torch.arange(length).expand(batch, length), "shared"),  # rows as an expand
    ]
    with torch.no_grad():
        for used, write_index, mask_kind in calls:
            x = torch.randn(batch, length, d, generator=gen)
            allowed = torch.rand(batch if mask_kind == "per" else 1, 1, length, used, generator=gen) > 0.4
            allowed[..., 0] = True  # every query attends at least one slot
            expected = torch_step(x, allowed, reference, write_index)
            torch.testing.assert_close(
                native_step(x, allowed, blocked, write_index), expected, rtol=0, atol=2e-5
            )
            for block in range(2):  # the new keys / values are computed: equal up to rounding
                torch.testing.assert_close(blocked.keys(block), reference.keys[block], rtol=0, atol=1e-6)
                torch.testing.assert_close(blocked.values[block], reference.values[block], rtol=0, atol=1e-6)


@requires_native
def test_native_step_follows_parameter_updates():
    model = transformer(128, 2, 64, 4, "none")
    torch_step, native_step = TransformerStep(model), NativeTransformerStep(model)
    x = torch.randn(1, 4, 128, generator=torch.Generator().manual_seed(2))
    mask = torch.ones(1, 1, 4, 9, dtype=torch.bool).tril(diagonal=5)

    def check():
        reference = KVCache.empty(2, 1, 2, 12, 64)
        blocked = BlockedKVCache.empty(2, 1, 2, 12, 64)
        expected = torch_step(x, mask, reference, slice(5, 9))
        torch.testing.assert_close(native_step(x, mask, blocked, slice(5, 9)), expected, rtol=0, atol=2e-5)

    with torch.no_grad():
        check()
        model.blocks[1].mlp[0].weight.mul_(-2.0)  # an in-place update of a Linear weight
        check()
        model.blocks[0].ln_attn.bias.add_(0.3)  # a parameter the kernel reads through its storage
        check()
        qkv = model.blocks[0].attn.qkv
        qkv.bias.data = torch.randn(qkv.bias.shape)  # a replaced tensor
        model.ln_final.weight.data = torch.rand(128)
        check()


@requires_native
def test_native_step_rejects_inputs_it_would_read_or_write_out_of_bounds():
    model = transformer(128, 2, 64, 4, "none")
    step = NativeTransformerStep(model)
    cache = BlockedKVCache.empty(2, 1, 2, 12, 64)
    x = torch.randn(1, 4, 128)
    mask = torch.zeros(1, 1, 4, 8)
    with torch.no_grad():
        with pytest.raises(ValueError, match="x: expected float32"):
            step(x.double(), mask, cache, slice(0, 4))
        with pytest.raises(ValueError, match="attn_mask"):
            step(x, torch.zeros(1, 1, 3, 8), cache, slice(0, 4))
        with pytest.raises(ValueError, match="attn_mask"):
            step(x, torch.zeros(1, 1, 4, 13), cache, slice(0, 4))
        with pytest.raises(ValueError, match="write_index"):
            step(x, mask, cache, slice(10, 14))
        with pytest.raises(ValueError, match="write_index"):
            step(x, mask, cache, torch.tensor([[0, 1, 2, 12]]))
        with pytest.raises(ValueError, match="cache: expected"):
            step(x, mask, BlockedKVCache.empty(2, 2, 2, 12, 64), slice(0, 4))


@pytest.mark.parametrize("native", [None, True])
def test_decoder_falls_back_or_names_why_the_kernel_cannot_run(native):
    torch.manual_seed(0)
    model = NavFormerModel(
        NavFormerConfig(context_tokens=24, d_embed=48, d_head=24)
    ).eval()  # not a multiple of 16
    assert "d_head=24" in native_support(model.transformer.gpt)
    if native:
        with pytest.raises(ValueError, match="native=True.*d_head=24"):
            IncrementalNavFormer(model, 1, native=native)
        return
    decoder = IncrementalNavFormer(model, 1, native=native)
    assert decoder.native is False
    frames = torch.zeros(1, 84, 84, 3, dtype=torch.uint8)
    assert decoder.step(frames, frames, torch.ones(1, 1), torch.zeros(1, 2)).shape == (1, 2)


def test_environment_variable_turns_the_kernel_off(monkeypatch):
    monkeypatch.setenv(build.DISABLE_VARIABLE, "0")
    status = native_status()
    assert not status.available and build.DISABLE_VARIABLE in status.reason
    model = NavFormerModel(NavFormerConfig(context_tokens=24)).eval()
    assert IncrementalNavFormer(model, 1).native is False
    with pytest.raises(ValueError, match="disabled"):
        IncrementalNavFormer(model, 1, native=True)


def test_build_without_a_compiler_says_so(tmp_path):
    with pytest.raises(NativeBuildError, match="'no-such-cc' is not on PATH"):
        build.build_library(cache_dir=tmp_path, compiler=["no-such-cc"])


def test_a_failing_compiler_leaves_nothing_under_the_cache(tmp_path):
    fake = tmp_path / "fake-cc"
    fake.write_text(
        '#!/bin/sh\nif [ "$1" = --version ]; then echo fake 1.0; exit 0; fi\necho boom >&2\nexit 1\n'
    )
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    cache = tmp_path / "cache"
    with pytest.raises(NativeBuildError, match="boom"):
        build.build_library(cache_dir=cache, compiler=[str(fake)])
    assert list(cache.iterdir()) == []  # no partial library, no temporary file


@requires_native
def test_the_library_is_cached_per_source_and_checked_when_loaded(tmp_path):
    cache = tmp_path / "cache"
    first = build.build_library(cache_dir=cache)
    built = first.stat().st_mtime_ns
    assert build.build_library(cache_dir=cache) == first and first.stat().st_mtime_ns == built  # reused
    build.load_library(first)
    other = tmp_path / "other.c"
    other.write_text("#include <stdint.h>\nint64_t navformer_step_abi(void) { return 99; }\n")
    foreign = build.build_library(source=other, cache_dir=cache)
    assert foreign != first  # another source, another file
    with pytest.raises(NativeBuildError, match="ABI version 99"):
        build.load_library(foreign)
    garbage = tmp_path / "garbage.so"
    garbage.write_bytes(b"not a library")
    with pytest.raises(NativeBuildError, match="loading"):
        build.load_library(garbage)


@requires_native
def test_the_portable_build_gives_the_same_results(tmp_path):
    """A compiler that rejects -march=native gets the portable flags; that build computes the same."""
    wrapper = tmp_path / "no-march-cc"
    real = build.compiler_command()
    wrapper.write_text(
        '#!/bin/sh\nfor arg in "$@"; do [ "$arg" = -march=native ] && { echo no >&2; exit 1; }; done\n'
        f'exec {" ".join(real)} "$@"\n'
    )
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IEXEC)
    library = build.load_library(build.build_library(cache_dir=tmp_path / "cache", compiler=[str(wrapper)]))
    model = transformer(128, 2, 64, 4, "none")
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(1, 4, 128, generator=gen)
    mask = torch.rand(1, 1, 4, 30, generator=gen) > 0.3
    mask[..., 0] = True
    caches = [BlockedKVCache.empty(2, 1, 2, 40, 64) for _ in range(2)]
    with torch.no_grad():
        portable = NativeTransformerStep(model, library)(x, mask, caches[0], slice(20, 24))
        tuned = NativeTransformerStep(model)(x, mask, caches[1], slice(20, 24))
    torch.testing.assert_close(portable, tuned, rtol=0, atol=2e-5)


def test_the_module_command_reports_the_status(monkeypatch, capsys):
    from navformer_rl.modules.decoding.native.__main__ import main

    monkeypatch.setenv(build.DISABLE_VARIABLE, "0")
    assert main() == 1
    assert "unavailable: disabled by NAVFORMER_NATIVE=0" in capsys.readouterr().err
    monkeypatch.delenv(build.DISABLE_VARIABLE)
    status = native_status()
    assert main() == (0 if status.available else 1)
    out = capsys.readouterr()
    assert status.reason in (out.out if status.available else out.err)
