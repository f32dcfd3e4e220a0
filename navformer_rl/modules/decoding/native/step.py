"""``TransformerStep``'s maths as one call into the compiled kernel, and the key/value cache it reads."""

from __future__ import annotations

import ctypes
from typing import NamedTuple

import torch
from torch import Tensor, nn

from navformer_rl.modules.decoding.native.build import NativeBuildError, native_status
from navformer_rl.modules.decoding.transformer_step import TransformerStep
from navformer_rl.modules.models.gpt import GPT2Blocks, KVCache
from navformer_rl.modules.models.ops.attention import additive_mask

LANES = 16
"""Slots per block of ``BlockedKVCache.keys_blocked`` (one 16-float vector of scores per block)."""

_POINTER, _INT, _DOUBLE = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
_BLOCK_POINTERS = (
    "ln_attn_weight ln_attn_bias qkv_weight qkv_bias proj_weight proj_bias "
    "ln_mlp_weight ln_mlp_bias fc_weight fc_bias out_weight out_bias keys_blocked values"
).split()


class _Block(ctypes.Structure):
    """Mirror of the C ``Block`` (one transformer block's weights and cache)."""

    _fields_ = [(name, _POINTER) for name in _BLOCK_POINTERS] + [
        ("ln_attn_eps", _DOUBLE),
        ("ln_mlp_eps", _DOUBLE),
    ]


class _Step(ctypes.Structure):
    """Mirror of the C ``Step`` (one call's shapes, inputs and outputs)."""

    _fields_ = [
        *(
            (name, _INT)
            for name in "batch length d heads d_head hidden slots used n_blocks gelu_tanh".split()
        ),
        ("x", _POINTER),
        ("out", _POINTER),
        ("write_slots", _POINTER),
        ("write_slots_batch_stride", _INT),
        ("write_start", _INT),
        ("mask", _POINTER),
        ("mask_batch_stride", _INT),
        ("mask_row_stride", _INT),
        ("ln_final_weight", _POINTER),
        ("ln_final_bias", _POINTER),
        ("ln_final_eps", _DOUBLE),
        ("scratch", _POINTER),
        ("blocks", _POINTER),
    ]


class BlockedKVCache:
    """Keys and values of every block in the layout ``NativeTransformerStep`` reads.

    keys_blocked[i]: ``[B, n_heads, ceil(S / 16), d_head, 16]``, slot ``s`` at block ``s // 16``, lane
    ``s % 16`` (the scores of 16 slots are one vector operation); values[i]: ``[B, n_heads, S, d_head]``.
    As with ``KVCache``, which slot holds which token is the caller's business (the attention mask).
    """

    def __init__(self, keys_blocked: list[Tensor], values: list[Tensor]) -> None:
        self.keys_blocked = keys_blocked
        self.values = values

    @classmethod
    def empty(
        cls,
        n_blocks: int,
        batch: int,
        n_heads: int,
        slots: int,
        d_head: int,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> BlockedKVCache:
        blocks = -(-slots // LANES)
        return cls(
            [
                torch.zeros(batch, n_heads, blocks, d_head, LANES, device=device, dtype=dtype)
                for _ in range(n_blocks)
            ],
            [torch.zeros(batch, n_heads, slots, d_head, device=device, dtype=dtype) for _ in range(n_blocks)],
        )

    @classmethod
    def from_kv_cache(cls, cache: KVCache) -> BlockedKVCache:
        """A copy of ``cache`` (keys / values ``[B, n_heads, S, d_head]`` per block) in this layout."""
        batch, heads, slots, d_head = cache.keys[0].shape
        blocked = cls.empty(
            len(cache.keys), batch, heads, slots, d_head, cache.keys[0].device, cache.keys[0].dtype
        )
        for target, keys in zip(blocked.keys_blocked, cache.keys):
            padded = keys.new_zeros(batch, heads, target.shape[2] * LANES, d_head)
            padded[:, :, :slots] = keys
            target.copy_(padded.view(batch, heads, -1, LANES, d_head).transpose(-1, -2))
        for target, values in zip(blocked.values, cache.values):
            target.copy_(values)
        return blocked

    @property
    def slots(self) -> int:
        return self.values[0].shape[2]

    def keys(self, block: int) -> Tensor:
        """Block ``block``'s keys as ``[B, n_heads, S, d_head]`` (a copy; ``KVCache.keys`` layout)."""
        blocked = self.keys_blocked[block]
        return blocked.transpose(-1, -2).flatten(2, 3)[:, :, : self.slots].contiguous()


class Dims(NamedTuple):
    """A ``GPT2Blocks``'s sizes: token width, heads, head width, MLP width."""

    d_embed: int
    n_heads: int
    d_head: int
    hidden: int


def transformer_dims(transformer: GPT2Blocks) -> Dims:
    return Dims(
        transformer.ln_final.normalized_shape[0],
        transformer.n_heads,
        transformer.d_head,
        transformer.blocks[0].mlp[0].out_features,
    )


def native_support(transformer: GPT2Blocks) -> str | None:
    """Why ``NativeTransformerStep`` cannot run ``transformer`` (None when it can)."""
    block = transformer.blocks[0]
    dims = transformer_dims(transformer)
    sizes = {"d_embed": dims.d_embed, "d_head": dims.d_head, "MLP width": dims.hidden}
    odd = [f"{name}={value}" for name, value in sizes.items() if value % LANES]
    if odd:
        return f"the kernel needs multiples of {LANES}, got {', '.join(odd)}"
    parameter = next(transformer.parameters())
    if parameter.device.type != "cpu" or parameter.dtype != torch.float32:
        return f"the kernel runs float32 on the CPU, the model is {parameter.dtype} on {parameter.device}"
    activations = [b.mlp[1] for b in transformer.blocks]  # the kernel takes one GELU form for all blocks
    if not all(isinstance(g, nn.GELU) and g.approximate == block.mlp[1].approximate for g in activations):
        return f"the kernel's MLP activation is one nn.GELU form in every block, got {activations!r}"
    return None


class _Call(NamedTuple):
    """What one (batch, length) keeps between calls: the ``_Step`` struct and its scratch buffer."""

    step: _Step
    scratch: Tensor


class NativeTransformerStep:
    """``TransformerStep`` as one call into ``transformer_step.c`` (same arguments, result to float rounding).

    ``step(x, attn_mask, cache, write_index)`` -> hidden ``[B, L, d]``, writing the L new keys/values into a
    ``BlockedKVCache``. At 4 tokens the torch path is ~80 small ops whose BLAS calls re-pack every weight
    matrix; the kernel streams each weight once and reads the cache once per head, in ~0.15 ms per step for
    the paper model (benchmarks/model.md). float32, CPU, single-threaded; the weights are followed as in
    ``TransformerStep`` (rebuilt when a Linear weight changes; the other parameters are read through their
    current storage). Not thread-safe: one call at a time per instance (a scratch buffer is shared).

    library: a loaded kernel (``build.load_library``); default: ``native_status()``'s.

    Raises:
        ValueError: the kernel is unavailable (the reason is in the message) or cannot run this model.
        NativeBuildError: ``library``'s structs differ from the mirrors here.
    """

    def __init__(self, transformer: GPT2Blocks, library: ctypes.CDLL | None = None) -> None:
        if library is None:
            status = native_status()
            if not status.available:
                raise ValueError(
                    f"NativeTransformerStep: the compiled kernel is unavailable: {status.reason}"
                )
            library = status.library
        unsupported = native_support(transformer)
        if unsupported is not None:
            raise ValueError(f"NativeTransformerStep: {unsupported}")
        self._library = library
        self._check_structs()
        self._function = self._library.navformer_transformer_step
        self._function.argtypes = [ctypes.POINTER(_Step)]
        self._function.restype = None
        self.transformer = transformer
        self._torch_step = TransformerStep(transformer)  # the Linear weights as [in, out], kept fresh
        self._other_tensors = tuple(
            tensor
            for block in self._torch_step.blocks
            for tensor in (block.ln_attn.weight, block.ln_attn.bias, block.qkv[1], block.proj[1],
                           block.ln_mlp.weight, block.ln_mlp.bias, block.fc[1], block.out[1])
        ) + (self._torch_step.ln_final.weight, self._torch_step.ln_final.bias)  # fmt: skip
        self._blocks_key: tuple | None = None
        self._blocks: ctypes.Array | None = None
        self._pointed_at: tuple | None = None  # the weights and cache the block structs point into
        self.dims = transformer_dims(transformer)
        self._calls: dict[tuple[int, int, int], _Call] = {}

    def _check_structs(self) -> None:
        size = self._library.navformer_step_struct_size
        size.restype, size.argtypes = _INT, [_INT]
        if (size(0), size(1)) != (ctypes.sizeof(_Step), ctypes.sizeof(_Block)):
            raise NativeBuildError(
                f"the kernel's structs ({size(0)}, {size(1)} bytes) do not match step.py's "
                f"({ctypes.sizeof(_Step)}, {ctypes.sizeof(_Block)}): delete the cached library to rebuild"
            )

    def __call__(
        self, x: Tensor, attn_mask: Tensor, cache: BlockedKVCache, write_index: Tensor | slice
    ) -> Tensor:
        """x float32 ``[B, L, d]`` -> hidden ``[B, L, d]``; the L new keys/values are written to ``cache``.

        attn_mask: bool or additive float32 ``[B or 1, 1, L, S']``, attention over the first S' slots (last
        dimension contiguous). write_index: a ``slice`` of L slots shared by every sequence, or long
        ``[B, L]`` slots (rows may be an ``expand`` of one). Shapes and slots are checked here: the kernel
        itself trusts them.
        """
        batch, length, _ = x.shape
        if attn_mask.dtype == torch.bool:
            attn_mask = additive_mask(attn_mask, torch.float32)
        self._check(x, attn_mask, cache, write_index)
        x = x.contiguous()
        out = torch.empty_like(x)
        step = self._call(batch, length, cache)
        step.x, step.out, step.used = x.data_ptr(), out.data_ptr(), attn_mask.shape[-1]
        step.mask = attn_mask.data_ptr()
        step.mask_batch_stride = attn_mask.stride(0) if attn_mask.shape[0] > 1 else 0
        step.mask_row_stride = attn_mask.stride(2)
        if isinstance(write_index, slice):
            step.write_slots, step.write_start = None, write_index.start
        else:
            if write_index.dtype != torch.long or write_index.stride(-1) != 1:
                write_index = write_index.to(torch.long).contiguous()
            step.write_slots = write_index.data_ptr()
            step.write_slots_batch_stride = write_index.stride(0)
        self._function(ctypes.byref(step))
        return out

    def _check(
        self, x: Tensor, attn_mask: Tensor, cache: BlockedKVCache, write_index: Tensor | slice
    ) -> None:
        """Raise ``ValueError`` on inputs the kernel would read or write out of bounds."""
        batch, length, d = x.shape
        dims, blocks = self.dims, len(self._torch_step.blocks)
        if x.dtype != torch.float32 or x.device.type != "cpu" or d != dims.d_embed:
            raise ValueError(
                f"x: expected float32 [B, L, {dims.d_embed}] on the CPU, got {x.dtype} {tuple(x.shape)} on "
                f"{x.device}"
            )
        expected = (batch, dims.n_heads, cache.slots, dims.d_head)
        counts = (len(cache.keys_blocked), len(cache.values))
        if tuple(cache.values[0].shape) != expected or counts != (blocks, blocks):
            raise ValueError(
                f"cache: expected {blocks} blocks of keys and values {expected}, got {counts[0]} / "
                f"{counts[1]} of {tuple(cache.values[0].shape)}"
            )
        mask_shape = tuple(attn_mask.shape)
        if (
            attn_mask.dtype != torch.float32
            or attn_mask.dim() != 4
            or mask_shape[0] not in (1, batch)
            or mask_shape[1:3] != (1, length)
            or not 0 < mask_shape[3] <= cache.slots
            or attn_mask.stride(-1) != 1
        ):
            raise ValueError(
                f"attn_mask: expected bool or float32 [{batch} or 1, 1, {length}, <= {cache.slots}] with a "
                f"contiguous last dimension, got {attn_mask.dtype} {mask_shape} strides {attn_mask.stride()}"
            )
        if isinstance(write_index, slice):
            start, stop = write_index.start, write_index.stop
            if start is None or stop != start + length or start < 0 or stop > cache.slots:
                raise ValueError(
                    f"write_index: expected slice(s, s + {length}) "
                    f"within {cache.slots} slots, got {write_index}"
                )
        elif tuple(write_index.shape) != (batch, length) or not (
            0 <= int(write_index.min()) and int(write_index.max()) < cache.slots
        ):
            raise ValueError(
                f"write_index: expected [{batch}, {length}] slots in [0, {cache.slots}), got shape "
                f"{tuple(write_index.shape)} with slots {int(write_index.min())}..{int(write_index.max())}"
            )

    def _call(self, batch: int, length: int, cache: BlockedKVCache) -> _Step:
        """The struct for ``batch x length`` tokens, pointing at the current weights and ``cache``."""
        weights = self._torch_step.transposed_weights()  # a new tuple whenever a weight changed
        key = (id(weights), id(cache), tuple(tensor.data_ptr() for tensor in self._other_tensors))
        if key != self._blocks_key:  # the ids are of objects the block structs keep alive (_pointed_at)
            self._blocks = self._block_structs(weights, cache)
            self._blocks_key, self._pointed_at = key, (weights, cache)
            for call in self._calls.values():
                self._point(call.step)
        call = self._calls.get((batch, length, cache.slots))
        if call is None:
            call = self._calls[batch, length, cache.slots] = self._new_call(batch, length, cache.slots)
        return call.step

    def _point(self, step: _Step) -> None:
        """Point ``step`` at the current block structs and final LayerNorm."""
        final = self._torch_step.ln_final
        step.blocks = ctypes.cast(self._blocks, _POINTER)
        step.ln_final_weight, step.ln_final_bias = final.weight.data_ptr(), final.bias.data_ptr()
        step.ln_final_eps = final.module.eps

    def _block_structs(self, weights: tuple[Tensor, ...], cache: BlockedKVCache) -> ctypes.Array:
        """One ``_Block`` per transformer block; checks every block's cache tensors once per cache."""
        batch, dims = cache.values[0].shape[0], self.dims
        shapes = {
            "keys_blocked": (batch, dims.n_heads, -(-cache.slots // LANES), dims.d_head, LANES),
            "values": (batch, dims.n_heads, cache.slots, dims.d_head),
        }
        for i, (keys, values) in enumerate(zip(cache.keys_blocked, cache.values)):
            for name, tensor in (("keys_blocked", keys), ("values", values)):
                if tuple(tensor.shape) != shapes[name]:
                    raise ValueError(
                        f"cache: block {i}'s {name} has shape {tuple(tensor.shape)}, expected {shapes[name]}"
                    )
        blocks = (_Block * len(self._torch_step.blocks))()
        for i, (block, struct) in enumerate(zip(self._torch_step.blocks, blocks)):
            qkv_t, proj_t, fc_t, out_t = weights[4 * i : 4 * i + 4]
            tensors = (
                block.ln_attn.weight, block.ln_attn.bias, qkv_t, block.qkv[1], proj_t, block.proj[1],
                block.ln_mlp.weight, block.ln_mlp.bias, fc_t, block.fc[1], out_t, block.out[1],
                cache.keys_blocked[i], cache.values[i],
            )  # fmt: skip
            for name, tensor in zip(_BLOCK_POINTERS, tensors):
                if not tensor.is_contiguous() or tensor.dtype != torch.float32 or tensor.device.type != "cpu":
                    raise ValueError(
                        f"NativeTransformerStep: block {i}'s {name} must be a contiguous float32 CPU tensor, "
                        f"got {tensor.dtype} on {tensor.device}, strides {tensor.stride()}"
                    )
                setattr(struct, name, tensor.data_ptr())
            struct.ln_attn_eps, struct.ln_mlp_eps = block.ln_attn.module.eps, block.ln_mlp.module.eps
        return blocks

    def _new_call(self, batch: int, length: int, slots: int) -> _Call:
        d, heads, d_head, hidden = self.dims
        floats = self._library.navformer_step_scratch_floats
        floats.restype, floats.argtypes = _INT, [_INT] * 6
        with torch.inference_mode(False):
            scratch = torch.empty(floats(batch * length, d, heads, d_head, hidden, slots))
        step = _Step(
            batch=batch, length=length, d=d, heads=heads, d_head=d_head, hidden=hidden, slots=slots,
            n_blocks=len(self._torch_step.blocks), scratch=scratch.data_ptr(),
            gelu_tanh=int(self._torch_step.blocks[0].gelu.approximate == "tanh"),
        )  # fmt: skip
        self._point(step)
        return _Call(step, scratch)
