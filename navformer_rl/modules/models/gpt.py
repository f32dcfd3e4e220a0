"""The causal transformer's N GPT-2 blocks (pre-LN) with an optional slot-addressed key/value cache
(paper §IV.C)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from navformer_rl.modules.models.config import NavFormerConfig
from navformer_rl.modules.models.ops.attention import attention_with_dropout
from navformer_rl.modules.models.ops.dropout import Dropout


@dataclass
class KVCache:
    """Keys and values of every block, addressed by slot.

    keys[i], values[i]: ``[B, n_heads, S, d_head]`` for block ``i``; ``S`` slots per sequence. Which slot
    holds which token (and whether it is valid) is the caller's business: it passes the attention mask.
    Attention is a weighted sum over keys, so slot order does not matter - a ring buffer works.

    slot_major[i] (``empty`` fills it): ``[B, S, 2, n_heads, d_head]``, the storage that ``keys[i]`` and
    ``values[i]`` are views of (``[..., 0, :, :]`` keys, ``[..., 1, :, :]`` values). One slot's keys and
    values of every head are contiguous, so a step's new keys and values go in with one copy, straight from
    the ``[B, L, 3, n_heads, d_head]`` projection (``TransformerStep``), and attention reads each slot once.
    None when ``keys``/``values`` are separate tensors.
    """

    keys: list[Tensor]
    values: list[Tensor]
    slot_major: list[Tensor] | None = None

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
    ) -> KVCache:
        storage = [
            torch.zeros(batch, slots, 2, n_heads, d_head, device=device, dtype=dtype) for _ in range(n_blocks)
        ]
        return cls(  # [B, S, 2, H, d_head] -> keys, values [B, H, S, d_head] (views)
            keys=[block[:, :, 0].transpose(1, 2) for block in storage],
            values=[block[:, :, 1].transpose(1, 2) for block in storage],
            slot_major=storage,
        )

    @property
    def slots(self) -> int:
        return self.keys[0].shape[2]


class CausalSelfAttention(nn.Module):
    """Masked multi-head attention (MMHA) through ``F.scaled_dot_product_attention``."""

    def __init__(self, d_embed: int, n_heads: int, d_head: int, dropout: float) -> None:
        super().__init__()
        self.n_heads, self.d_head, self.dropout = n_heads, d_head, dropout
        self.qkv = nn.Linear(d_embed, 3 * n_heads * d_head)
        self.proj = nn.Linear(n_heads * d_head, d_embed)
        self.resid_dropout = Dropout(dropout)

    def forward(
        self,
        x: Tensor,
        attn_mask: Tensor | None,
        cache: tuple[Tensor, Tensor] | None,
        write_index: Tensor | slice | None,
    ) -> Tensor:
        """x: ``[B, L, d]``. Without ``attn_mask``: plain causal attention among the L tokens.

        With ``cache = (keys, values)`` (``[B, H, S, d_head]``), the new keys/values are written at
        ``write_index`` (long ``[B, L]``, slots; or a ``slice`` of L slots shared by every sequence, one
        copy instead of a scatter) and the queries attend over the first S' slots under ``attn_mask``
        (bool ``[B or 1, 1, L, S']``, True = may attend, or additive float 0 / -inf; S' <= S).
        """
        batch, length, _ = x.shape
        # [B, L, 3 * H * d_head] -> [B, L, 3, H, d_head] -> q, k, v [B, H, L, d_head]
        q, k, v = self.qkv(x).view(batch, length, 3, self.n_heads, self.d_head).permute(2, 0, 3, 1, 4)
        if cache is not None:
            cache_k, cache_v = cache
            if isinstance(write_index, slice):  # every sequence writes the same contiguous slots
                cache_k[:, :, write_index] = k
                cache_v[:, :, write_index] = v
            else:
                # slots [B, L] -> [B, H, L, d_head], the index of each new key / value along the slots
                index = write_index[:, None, :, None].expand(batch, self.n_heads, length, self.d_head)
                cache_k.scatter_(2, index, k.to(cache_k.dtype))
                cache_v.scatter_(2, index, v.to(cache_v.dtype))
            used = attn_mask.shape[-1]  # the caller may restrict attention to the first slots in use
            k, v = cache_k[:, :, :used], cache_v[:, :, :used]
        dropout_p = self.dropout if self.training else 0.0
        if dropout_p > 0.0 and x.device.type == "cpu":
            y = attention_with_dropout(q, k, v, attn_mask, dropout_p)
        else:
            y = F.scaled_dot_product_attention(
                q, k, v, attn_mask=attn_mask, dropout_p=dropout_p, is_causal=attn_mask is None
            )
        y = y.transpose(1, 2).reshape(
            batch, length, self.n_heads * self.d_head
        )  # [B, H, L, dh] -> [B, L, H dh]
        return self.resid_dropout(self.proj(y))


class TransformerBlock(nn.Module):
    """GPT-2 block: ``x + MMHA(LN(x))`` then ``x + MLP(LN(x))``
    with MLP = Linear(d, 4d) - GELU - Linear(4d, d).

    GELU is the exact (erf) one: GPT-2's tanh approximation differs by < 1e-3 and costs 2-3x more on CPU."""

    def __init__(self, d_embed: int, n_heads: int, d_head: int, mlp_ratio: int, dropout: float) -> None:
        super().__init__()
        self.ln_attn = nn.LayerNorm(d_embed)
        self.attn = CausalSelfAttention(d_embed, n_heads, d_head, dropout)
        self.ln_mlp = nn.LayerNorm(d_embed)
        self.mlp = nn.Sequential(
            nn.Linear(d_embed, mlp_ratio * d_embed),
            nn.GELU(),
            nn.Linear(mlp_ratio * d_embed, d_embed),
            Dropout(dropout),
        )

    def forward(
        self,
        x: Tensor,
        attn_mask: Tensor | None,
        cache: tuple[Tensor, Tensor] | None,
        write_index: Tensor | slice | None,
    ) -> Tensor:
        x = x + self.attn(self.ln_attn(x), attn_mask, cache, write_index)
        return x + self.mlp(self.ln_mlp(x))


class GPT2Blocks(nn.Module):
    """N GPT-2 blocks and a final LayerNorm: ``[B, L, d] -> [B, L, d]`` (the body of ``CausalTransformer``).

    No positional embedding inside: the caller adds timestep and modality embeddings to the tokens, so
    a token's key/value never depends on where it sits in the window (what makes the sliding KV cache valid).
    Padding: sequences are right-padded; under causal attention padded tokens never influence valid ones.
    """

    def __init__(
        self, d_embed: int, n_blocks: int, n_heads: int, d_head: int, mlp_ratio: int, dropout: float
    ) -> None:
        super().__init__()
        self.n_blocks, self.n_heads, self.d_head = n_blocks, n_heads, d_head
        self.blocks = nn.ModuleList(
            TransformerBlock(d_embed, n_heads, d_head, mlp_ratio, dropout) for _ in range(n_blocks)
        )
        self.ln_final = nn.LayerNorm(d_embed)
        self.apply(_init_gpt2)
        for name, param in self.named_parameters():
            if name.endswith("attn.proj.weight") or name.endswith("mlp.2.weight"):
                nn.init.normal_(param, mean=0.0, std=0.02 / (2 * n_blocks) ** 0.5)

    @classmethod
    def from_config(cls, config: NavFormerConfig) -> GPT2Blocks:
        return cls(
            config.d_embed, config.n_blocks, config.n_heads, config.d_head, config.mlp_ratio, config.dropout
        )

    def forward(
        self,
        x: Tensor,
        attn_mask: Tensor | None = None,
        kv_cache: KVCache | None = None,
        write_index: Tensor | slice | None = None,
    ) -> tuple[Tensor, KVCache | None]:
        """x: ``[B, L, d]`` -> (hidden ``[B, L, d]``, the updated ``kv_cache``).

        attn_mask: bool, True = may attend; ``[B or 1, 1, L, L]`` without a cache, ``[B, 1, L, S']`` with
        one (attention over the first S' <= S slots); None means causal among the L tokens (no cache only).
        kv_cache / write_index: incremental mode (inference, no autograd): the L new tokens' keys and
        values are written in place at slots ``write_index`` (long ``[B, L]``, or a ``slice`` of L slots
        shared by the whole batch) before attending.
        """
        if kv_cache is not None and (write_index is None or attn_mask is None):
            raise ValueError("GPT2Blocks: a kv_cache needs both write_index and attn_mask")
        for i, block in enumerate(self.blocks):
            cache = None if kv_cache is None else (kv_cache.keys[i], kv_cache.values[i])
            x = block(x, attn_mask, cache, write_index)
        return self.ln_final(x), kv_cache


def _init_gpt2(module: nn.Module) -> None:
    """GPT-2 initialisation: N(0, 0.02) weights, zero biases, unit LayerNorm."""
    if isinstance(module, nn.Linear):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
        nn.init.zeros_(module.bias)
    elif isinstance(module, nn.LayerNorm):
        nn.init.ones_(module.weight)
        nn.init.zeros_(module.bias)
