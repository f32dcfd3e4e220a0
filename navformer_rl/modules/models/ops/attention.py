"""Attention with dropout on the weights, for training on CPU, in cache-sized chunks of sequences.

``F.scaled_dot_product_attention`` with ``dropout_p > 0`` falls back on CPU to its math path, which runs
every step (scores, softmax, dropout, product) over the whole ``[B * H, L, S]`` weights: in the paper's
batch B that is ``[300, 252, 252]``, 38 MB in bf16, so each of the ~10 elementwise passes of the forward
and backward goes through main memory. ``attention_with_dropout`` computes the same thing chunk by chunk
over the ``B * H`` sequences (``CHUNK_BYTES`` of weights per chunk, 33 sequences at L = S = 252 in bf16),
so the passes on a chunk stay in the core's cache; a custom backward walks the chunks again. The values
and gradients are bit-identical to the unchunked autograd graph of the same ops (tested); a whole
attention forward + backward takes 0.67-0.83x the time of the unchunked one (``benchmarks/model.md``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from navformer_rl.modules.models.ops.dropout import keep_mask

CHUNK_BYTES = 4 << 20  # attention weights per chunk (the machine's L2 is 2 MB per core: 4 MB over 2 cores)


def additive_mask(allowed: Tensor, dtype: torch.dtype) -> Tensor:
    """Bool attention mask (True = may attend) -> the additive one SDPA adds to the scores (0 / -inf).

    SDPA converts a bool mask to this form in every call (every block); converting once per step is cheaper.
    """
    return torch.zeros(allowed.shape, dtype=dtype, device=allowed.device).masked_fill_(
        allowed.logical_not(), float("-inf")
    )


def attention_with_dropout(q: Tensor, k: Tensor, v: Tensor, attn_mask: Tensor | None, p: float) -> Tensor:
    """``softmax(q k^T / sqrt(d_head) | mask)`` with dropout p on the weights, then ``@ v``.

    What ``F.scaled_dot_product_attention(..., dropout_p=p)`` computes (on CPU its math path: the fused
    kernels do not support dropout there), with the mask drawn by ``keep_mask``, far cheaper than SDPA's
    ``bernoulli_`` on the ``[B, H, L, S]`` weights, and the 1 / (1 - p) rescaling applied to the smaller
    output. q: ``[B, H, L, d_head]``, k / v: ``[B, H, S, d_head]``; attn_mask bool ``[B or 1, 1, L, S]``
    (True = may attend) or None (causal, L = S) -> ``[B, H, L, d_head]``, in q's dtype (k and v are cast
    to it, as autocast would).
    """
    batch, heads, length, d_head = q.shape
    slots = k.shape[-2]
    if attn_mask is None:
        attn_mask = torch.ones(length, slots, dtype=torch.bool, device=q.device).tril_()
    bias = additive_mask(attn_mask, q.dtype)
    if bias.dim() == 4:  # [B or 1, 1, L, S] -> [L, S] or the [B * H, L, S] scores' shape
        bias = bias[0, 0] if bias.shape[0] == 1 else bias.expand(batch, heads, length, slots).flatten(0, 1)
    keep = keep_mask((batch * heads, length, slots), 1.0 - p, q.device)
    out = chunked_dropout_attention(
        q.flatten(0, 1),
        k.flatten(0, 1).to(q.dtype),
        v.flatten(0, 1).to(q.dtype),
        bias,
        keep,
        scale=1.0 / (1.0 - p),
    )
    return out.view(batch, heads, length, d_head)


def chunked_dropout_attention(
    q: Tensor, k: Tensor, v: Tensor, bias: Tensor, keep: Tensor, scale: float, chunk: int | None = None
) -> Tensor:
    """``(softmax(q k^T / sqrt(d) + bias) * keep) @ v * scale`` over ``chunk`` sequences at a time.

    q: ``[N, L, d]``; k, v: ``[N, S, d]``, all of one dtype; bias: additive, ``[L, S]`` (shared) or
    ``[N, L, S]``; keep: bool ``[N, L, S]`` (False = dropped); -> ``[N, L, d]``. ``chunk`` defaults to
    ``CHUNK_BYTES`` of weights. Differentiable in q, k and v; the backward keeps the softmax weights
    (``[N, L, S]`` in q's dtype, as autograd would) and ``keep``, not the scores.
    """
    if not q.dtype == k.dtype == v.dtype:
        raise ValueError(f"q, k, v: expected one dtype, got {q.dtype}, {k.dtype}, {v.dtype}")
    n, length, slots = q.shape[0], q.shape[1], k.shape[1]
    if keep.shape != (n, length, slots) or keep.dtype != torch.bool:
        raise ValueError(
            f"keep: expected bool [{n}, {length}, {slots}], got {keep.dtype} {tuple(keep.shape)}"
        )
    if tuple(bias.shape) not in ((length, slots), (n, length, slots)):
        raise ValueError(
            f"bias: expected [{length}, {slots}] or [{n}, {length}, {slots}], got {tuple(bias.shape)}"
        )
    if chunk is None:
        chunk = max(1, CHUNK_BYTES // (length * slots * q.element_size()))
    elif chunk < 1:
        raise ValueError(f"chunk={chunk!r}: expected a positive number of sequences or None")
    return _ChunkedDropoutAttention.apply(q, k, v, bias.to(q.dtype), keep, scale, chunk)


class _ChunkedDropoutAttention(torch.autograd.Function):
    """Forward and backward of ``chunked_dropout_attention``, chunk by chunk, autocast off
    (explicit dtypes)."""

    @staticmethod
    def forward(ctx, q, k, v, bias, keep, scale, chunk):
        with torch.autocast(q.device.type, enabled=False):
            alpha = q.shape[-1] ** -0.5
            weights = torch.empty(q.shape[0], q.shape[1], k.shape[1], dtype=q.dtype, device=q.device)
            out = torch.empty(q.shape[:-1] + v.shape[-1:], dtype=q.dtype, device=q.device)
            for part in _chunks(q.shape[0], chunk):
                part_bias = bias if bias.dim() == 2 else bias[part]
                scores = torch.baddbmm(part_bias, q[part], k[part].transpose(1, 2), alpha=alpha)
                torch.ops.aten._softmax.out(scores, -1, False, out=weights[part])
                torch.bmm(weights[part] * _as_factor(keep[part], q.dtype), v[part], out=out[part])
            out.mul_(scale)
        ctx.save_for_backward(q, k, v, weights, keep)
        ctx.alpha, ctx.scale, ctx.chunk = alpha, scale, chunk
        return out

    @staticmethod
    def backward(ctx, grad_out):
        q, k, v, weights, keep = ctx.saved_tensors
        with torch.autocast(q.device.type, enabled=False):
            grad_out = grad_out.to(q.dtype) * ctx.scale
            grad_q, grad_k, grad_v = torch.empty_like(q), torch.empty_like(k), torch.empty_like(v)
            for part in _chunks(q.shape[0], ctx.chunk):
                w, factor = weights[part], _as_factor(keep[part], q.dtype)
                torch.bmm((w * factor).transpose(1, 2), grad_out[part], out=grad_v[part])
                grad_w = torch.bmm(grad_out[part], v[part].transpose(1, 2)).mul_(factor)
                grad_scores = torch._softmax_backward_data(grad_w, w, -1, w.dtype)
                torch.bmm(grad_scores, k[part], out=grad_q[part]).mul_(ctx.alpha)
                torch.bmm(grad_scores.transpose(1, 2), q[part], out=grad_k[part]).mul_(ctx.alpha)
        return grad_q, grad_k, grad_v, None, None, None, None


def _chunks(n: int, chunk: int) -> list[slice]:
    return [slice(start, start + chunk) for start in range(0, n, chunk)]


def _as_factor(keep: Tensor, dtype: torch.dtype) -> Tensor:
    """Bool mask -> 0 / 1 in ``dtype`` through its uint8 view
    (the bool conversion is not vectorised on CPU)."""
    return keep.view(torch.uint8).to(dtype)
