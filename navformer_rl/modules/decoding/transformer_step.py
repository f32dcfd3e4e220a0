"""Inference helper: the causal transformer on a few new tokens against a KV cache, without module calls."""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from navformer_rl.modules.decoding.derived import DerivedCache
from navformer_rl.modules.models.gpt import GPT2Blocks, KVCache


class LayerNormWeights(NamedTuple):
    """A LayerNorm's parameters; ``eps`` and the shape are read from ``module`` at every call."""

    weight: Tensor
    bias: Tensor
    module: nn.LayerNorm

    def __call__(self, x: Tensor) -> Tensor:
        return F.layer_norm(x, self.module.normalized_shape, self.weight, self.bias, self.module.eps)


class BlockWeights(NamedTuple):
    """One ``TransformerBlock``'s parameters: ``(weight [out, in], bias)`` per Linear, as ``F.linear`` takes.

    ``gelu``: the MLP's ``nn.GELU`` (its ``approximate`` is read at every call).
    """

    ln_attn: LayerNormWeights
    qkv: tuple[Tensor, Tensor]
    proj: tuple[Tensor, Tensor]
    ln_mlp: LayerNormWeights
    fc: tuple[Tensor, Tensor]
    out: tuple[Tensor, Tensor]
    gelu: nn.GELU


class TransformerStep:
    """``GPT2Blocks.forward`` with a KV cache (eval mode), as a loop of plain tensor ops.

    ``step(x, attn_mask, cache, write_index)`` equals ``transformer(x, attn_mask, cache, write_index)[0]``
    (same maths, no dropout). With 4 new tokens every op is tiny, so module calls (``nn.Module.__call__``
    and ``__getattr__`` cost microseconds each), reshapes and 3-d ``F.linear`` cost about as much as the
    maths: this loop takes ~0.7x the time of the module path. The Linear weights are kept transposed
    (``[in, out]``, contiguous) for ``addmm``, which at 4 rows takes 10-12 us against 15-19 us for
    ``F.linear`` on the ``[out, in]`` weight (that re-packs it at every call); the copies are rebuilt
    whenever a weight changes (in place, ``model.to`` or ``load_state_dict``; ``derived.parameter_key``
    lists what is not seen: ``p.data`` writes, fused optimizers). The blocks' other ``Parameter`` objects
    are used directly. A sub-module replaced by a
    new one is not seen: make a new ``TransformerStep`` then. No autograd (the qkv projection is written
    into a kept buffer): call it under ``torch.no_grad()`` or inference mode.
    """

    def __init__(self, transformer: GPT2Blocks) -> None:
        self.transformer = transformer
        self.blocks = tuple(block_weights(block) for block in transformer.blocks)
        self.ln_final = layer_norm_weights(transformer.ln_final)
        self._weights = tuple(
            linear[0] for block in self.blocks for linear in (block.qkv, block.proj, block.fc, block.out)
        )
        self._transposed = DerivedCache(self._weights)
        self._buffers: dict[tuple, ProjectionBuffers] = {}

    def _build_transposed(self) -> tuple[Tensor, ...]:
        return tuple(weight.detach().t().contiguous() for weight in self._weights)

    def transposed_weights(self) -> tuple[Tensor, ...]:
        """Every block's ``(qkv, proj, fc, out)`` weights as contiguous ``[in, out]`` (rebuilt if changed)."""
        return self._transposed.get(self._build_transposed)

    def __call__(self, x: Tensor, attn_mask: Tensor, cache: KVCache, write_index: Tensor | slice) -> Tensor:
        """x ``[B, L, d]`` -> hidden ``[B, L, d]``; the L new keys/values are written to ``cache``.

        attn_mask: bool or additive float ``[B or 1, 1, L, S']``, attention over the first S' slots.
        write_index: a ``slice`` of L slots shared by every sequence, or long ``[B, L]`` slots.
        """
        batch, length, d = x.shape
        used = attn_mask.shape[-1]
        whole_cache = used == cache.slots  # past the ring's wrap: attend every slot, no slicing
        transposed = self.transposed_weights()
        buffers = self._projection_buffers(batch, length, x.dtype, x.device)
        h = x.reshape(batch * length, d)
        for i, (block, keys, values) in enumerate(zip(self.blocks, cache.keys, cache.values)):
            qkv_t, proj_t, fc_t, out_t = transposed[4 * i : 4 * i + 4]
            torch.addmm(block.qkv[1], block.ln_attn(h), qkv_t, out=buffers.qkv)
            if cache.slot_major is not None:  # keys and values of the new slots in one copy
                write_slots(cache.slot_major[i], buffers.keys_values, write_index, dim=1)
            else:
                write_slots(keys, buffers.keys, write_index)
                write_slots(values, buffers.values, write_index)
            if not whole_cache:
                keys, values = keys[:, :, :used], values[:, :, :used]
            y = F.scaled_dot_product_attention(buffers.queries, keys, values, attn_mask=attn_mask)
            h = torch.addmm(block.proj[1], y.transpose(1, 2).reshape(batch * length, -1), proj_t).add_(h)
            hidden = F.gelu(
                torch.addmm(block.fc[1], block.ln_mlp(h), fc_t), approximate=block.gelu.approximate
            )
            h = torch.addmm(block.out[1], hidden, out_t).add_(h)
        return self.ln_final(h).view(batch, length, d)

    def _projection_buffers(
        self, batch: int, length: int, dtype: torch.dtype, device: torch.device
    ) -> ProjectionBuffers:
        """The qkv projection's output buffer for ``batch x length`` tokens and its views (made once).

        Allocated outside inference mode: an inference tensor could not be written by a later call made
        under plain ``no_grad``. Each block overwrites it: its views are read before the next block runs.
        """
        key = (batch, length, dtype, device)
        buffers = self._buffers.get(key)
        if buffers is None:
            heads, d_head = self.transformer.n_heads, self.transformer.d_head
            with torch.inference_mode(False):
                qkv = torch.empty(batch * length, 3 * heads * d_head, dtype=dtype, device=device)
                split = qkv.view(batch, length, 3, heads, d_head)
                buffers = ProjectionBuffers(
                    qkv,
                    split[:, :, 0].transpose(1, 2),
                    split[:, :, 1:],
                    split[:, :, 1].transpose(1, 2),
                    split[:, :, 2].transpose(1, 2),
                )
            self._buffers[key] = buffers
        return buffers


class ProjectionBuffers(NamedTuple):
    """The qkv projection of L new tokens: ``qkv`` ``[B * L, 3 * H * d_head]`` and views of it.

    queries ``[B, H, L, d_head]``; keys_values ``[B, L, 2, H, d_head]`` (for ``KVCache.slot_major``); keys,
    values ``[B, H, L, d_head]``.
    """

    qkv: Tensor
    queries: Tensor
    keys_values: Tensor
    keys: Tensor
    values: Tensor


def write_slots(cache: Tensor, new: Tensor, write_index: Tensor | slice, dim: int = 2) -> None:
    """Write ``new`` into ``cache`` at slots ``write_index`` along ``dim``, the slot dimension.

    ``dim=2``: ``new`` ``[B, H, L, d_head]`` into keys or values ``[B, H, S, d_head]``; ``dim=1``: ``new``
    ``[B, L, 2, H, d_head]`` into a ``KVCache.slot_major`` tensor ``[B, S, 2, H, d_head]``. write_index: a
    ``slice`` of L slots shared by the batch, or long ``[B, L]``.
    """
    if isinstance(write_index, slice):
        cache[(slice(None),) * dim + (write_index,)] = new
    else:
        shape = (*write_index.shape[:2], *(1,) * (new.dim() - 2))
        index = write_index.view(shape).movedim(1, dim).expand(new.shape)
        cache.scatter_(dim, index, new.to(cache.dtype))


def layer_norm_weights(norm: nn.LayerNorm) -> LayerNormWeights:
    return LayerNormWeights(norm.weight, norm.bias, norm)


def block_weights(block: nn.Module) -> BlockWeights:
    """A ``TransformerBlock``'s parameters (raises ``ValueError`` on an unexpected structure)."""
    fc, gelu, out = block.mlp[0], block.mlp[1], block.mlp[2]
    if not isinstance(gelu, nn.GELU):
        raise ValueError(
            f"TransformerStep: expected the block's MLP to use nn.GELU, got {type(gelu).__name__}"
        )
    attn = block.attn
    return BlockWeights(
        layer_norm_weights(block.ln_attn),
        (attn.qkv.weight, attn.qkv.bias),
        (attn.proj.weight, attn.proj.bias),
        layer_norm_weights(block.ln_mlp),
        (fc.weight, fc.bias),
        (out.weight, out.bias),
        gelu,
    )
