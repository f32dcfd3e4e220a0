"""Inference helper: the causal transformer on a few new tokens against a KV cache, without module calls."""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from navformer_rl.modules.models.derived import DerivedCache
from navformer_rl.modules.models.transformer import CausalTransformer, KVCache


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
    """``CausalTransformer.forward`` with a KV cache (eval mode), as a loop of plain tensor ops.

    ``step(x, attn_mask, cache, write_index)`` equals ``transformer(x, attn_mask, cache, write_index)[0]``
    (same maths, no dropout). With 4 new tokens every op is tiny, so module calls (``nn.Module.__call__``
    and ``__getattr__`` cost microseconds each), reshapes and 3-d ``F.linear`` cost about as much as the
    maths: this loop takes ~0.7x the time of the module path. The Linear weights are kept transposed
    (``[in, out]``, contiguous) for ``addmm``, which at 4 rows takes 10-12 us against 15-19 us for
    ``F.linear`` on the ``[out, in]`` weight (that re-packs it at every call); the copies are rebuilt
    whenever a weight changes (in place, through ``.data``, ``model.to`` or ``load_state_dict``), so they
    are never stale. The blocks' other ``Parameter`` objects are used directly. A sub-module replaced by a
    new one is not seen: make a new ``TransformerStep`` then.
    """

    def __init__(self, transformer: CausalTransformer) -> None:
        self.transformer = transformer
        self.blocks = tuple(block_weights(block) for block in transformer.blocks)
        self.ln_final = layer_norm_weights(transformer.ln_final)
        weights = tuple(
            linear[0] for block in self.blocks for linear in (block.qkv, block.proj, block.fc, block.out)
        )
        self._transposed = DerivedCache(
            weights, lambda: tuple(weight.detach().t().contiguous() for weight in weights)
        )

    def transposed_weights(self) -> tuple[Tensor, ...]:
        """Every block's ``(qkv, proj, fc, out)`` weights as contiguous ``[in, out]`` (rebuilt if changed)."""
        return self._transposed.get()

    def __call__(self, x: Tensor, attn_mask: Tensor, cache: KVCache, write_index: Tensor | slice) -> Tensor:
        """x ``[B, L, d]`` -> hidden ``[B, L, d]``; the L new keys/values are written to ``cache``.

        attn_mask: bool or additive float ``[B or 1, 1, L, S']``, attention over the first S' slots.
        write_index: a ``slice`` of L slots shared by every sequence, or long ``[B, L]`` slots.
        """
        batch, length, d = x.shape
        heads, d_head = self.transformer.n_heads, self.transformer.d_head
        used = attn_mask.shape[-1]
        transposed = self.transposed_weights()
        h = x.reshape(batch * length, d)
        for i, (block, keys, values) in enumerate(zip(self.blocks, cache.keys, cache.values)):
            qkv_t, proj_t, fc_t, out_t = transposed[4 * i : 4 * i + 4]
            qkv = torch.addmm(block.qkv[1], block.ln_attn(h), qkv_t).view(batch, length, 3, heads, d_head)
            if cache.slot_major is not None:  # keys and values of the new slots in one copy
                write_slots(cache.slot_major[i], qkv[:, :, 1:], write_index, dim=1)
            else:
                write_slots(keys, qkv[:, :, 1].transpose(1, 2), write_index)
                write_slots(values, qkv[:, :, 2].transpose(1, 2), write_index)
            q = qkv[:, :, 0].transpose(1, 2)  # [B, H, L, d_head]
            y = F.scaled_dot_product_attention(q, keys[:, :, :used], values[:, :, :used], attn_mask=attn_mask)
            h = torch.addmm(
                block.proj[1], y.transpose(1, 2).reshape(batch * length, heads * d_head), proj_t
            ).add_(h)
            hidden = F.gelu(
                torch.addmm(block.fc[1], block.ln_mlp(h), fc_t), approximate=block.gelu.approximate
            )
            h = torch.addmm(block.out[1], hidden, out_t).add_(h)
        return self.ln_final(h).view(batch, length, d)


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
