"""How the navigation network reads the target: its attention to the target token, and THSC's target term.

Two readings of one checkpoint, teacher-forced on held-out windows beside the probes of
:mod:`~navformer_rl.evaluation.diagnose.probe`:

- **attention to the target token**: in each transformer block, the attention weight (averaged over the
  heads) that the token whose hidden state the action head reads (step t's last observation token: e^ca_t,
  DT's e_t) puts on the target token e_g at position 0. It is the only way the target image reaches the
  action: the target token sits first in a causal sequence, so its own hidden state h_g sees nothing else.
  Weights are also given relative to uniform attention over the same keys (``weight x number of keys``):
  NavFormer's 4 tokens per step give more keys at the same step than DT's 3.
- **THSC's target term**: THSC's head is ``tanh(W_g h_g + W_o h^ca_o + b)`` (paper §IV.C). Since h_g depends
  on the target image alone, ``W_g h_g`` is one offset per trajectory, added to every step's action;
  how much it varies between targets, against how much ``W_o h^ca_o`` varies between frames, says whether
  the concatenation carries anything target-specific.
- **a swapped target**: the same windows with each trajectory's target image replaced by another target of
  the dataset (:class:`TargetSwap`). D_e has one target object per maze, so with the swapped image the object
  in view is not the one sought: a policy that recognises its target changes its action, and turns towards the
  object less; one that heads for any target-like object does not.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

READINGS = (
    "attention_to_target",
    "attention_keys",
    "target_term",
    "observation_term",
    "action_own",
    "action_swapped",
)
"""The per-frame arrays :class:`TargetAttentionRecorder`, :func:`head_terms` and :class:`TargetSwap` add to
the probe's frames."""


def attention_weights(attention: nn.Module, x: Tensor, query_positions: Tensor) -> Tensor:
    """The causal attention weights of ``attention`` (a ``CausalSelfAttention``) at some query positions.

    Args:
        attention: the block's attention module (its ``qkv`` projection, ``n_heads`` and ``d_head``).
        x: float ``[B, L, d]``, the block's attention input (after its LayerNorm).
        query_positions: int64 ``[Q]``, positions in ``[0, L)``.

    Returns:
        float32 ``[B, H, Q, L]``: ``softmax(q k^T / sqrt(d_head))`` over the keys ``<=`` each query's
        position (0 beyond it), computed in float32.
    """
    batch, length, _ = x.shape
    with torch.autocast(x.device.type, enabled=False):  # the model's forward may run under autocast
        qkv = nn.functional.linear(x.float(), attention.qkv.weight.float(), attention.qkv.bias.float())
        q, k, _ = qkv.view(batch, length, 3, attention.n_heads, attention.d_head).permute(2, 0, 3, 1, 4)
        scores = q[:, :, query_positions] @ k.transpose(-1, -2) / math.sqrt(attention.d_head)  # [B, H, Q, L]
        future = torch.arange(length, device=x.device)[None, :] > query_positions[:, None]  # [Q, L]
        return scores.masked_fill(future, float("-inf")).softmax(dim=-1)


class TargetAttentionRecorder:
    """Records, during a plain causal forward of a ``CausalTransformer``, the attention each step's
    head-read token puts on the target token, in every block.

    Use as a context manager around ``model.transformer(...)`` (no ``window_steps``, no cache); then
    ``weights`` is float32 ``[B, T, n_blocks]`` for the last forward and ``keys`` int64 ``[T]`` the number of
    keys step t's query attends over.
    """

    def __init__(self, transformer: nn.Module) -> None:
        self._blocks = list(transformer.gpt.blocks)
        self._tps = transformer.tokens_per_step
        self._handles: list[Any] = []
        self._rows: list[Tensor] = []
        self.weights: Tensor | None = None
        self.keys: Tensor | None = None

    def _hook(self, module: nn.Module, args: tuple[Any, ...], output: Tensor) -> None:
        x = args[0]
        if args[1] is not None or args[2] is not None:
            raise ValueError("TargetAttentionRecorder: expected a plain causal forward (no mask, no cache)")
        steps = (x.shape[1] + 1) // self._tps
        positions = torch.arange(1, steps + 1, device=x.device) * self._tps - 1  # step t's head-read token
        self.keys = (positions + 1).cpu()
        self._rows.append(attention_weights(module, x, positions)[..., 0].mean(dim=1))  # [B, T]

    def __enter__(self) -> TargetAttentionRecorder:
        self._rows = []
        self._handles = [block.attn.register_forward_hook(self._hook) for block in self._blocks]
        return self

    def __exit__(self, *exc: object) -> None:
        for handle in self._handles:
            handle.remove()
        self._handles = []
        if len(self._rows) == len(self._blocks):
            self.weights = torch.stack(self._rows, dim=-1)


class TargetSwap:
    """Replaces each target image by another of a dataset's targets: the next of its distinct target images in
    a fixed (lexicographic) order, so every kind of target maps to one other kind.

    ``TargetSwap(targets uint8 [n, H, W, 3])``; ``available`` is False with fewer than two distinct images;
    ``swap(images uint8 [B, H, W, 3]) -> [B, H, W, 3]``.
    """

    def __init__(self, targets: Tensor) -> None:
        self._distinct = torch.unique(torch.as_tensor(targets).flatten(1), dim=0)  # [U, H * W * 3]
        self._shape = tuple(targets.shape[1:])
        self.available = len(self._distinct) >= 2

    def swap(self, images: Tensor) -> Tensor:
        flat = images.flatten(1).to(self._distinct.device)
        match = (flat[:, None, :] == self._distinct[None]).all(dim=-1)  # [B, U]
        if not match.any(dim=1).all():
            raise ValueError("TargetSwap: an image is not one of the dataset's target images")
        index = (match.int().argmax(dim=1) + 1) % len(self._distinct)
        return self._distinct[index].view(len(images), *self._shape).to(images.device)


def head_terms(head: nn.Module, target_hidden: Tensor, observation_hidden: Tensor) -> dict[str, Tensor]:
    """The pre-``tanh`` parts of a linear action head's output, float32 ``[..., A]`` each.

    ``{"observation_term": W_o h_o}``, plus ``"target_term": W_g h_g`` for THSC (a head reading
    ``("target", "observation")``); empty for a head without a single ``weight`` (the binned head).
    """
    weight = getattr(head, "weight", None)
    if not isinstance(weight, Tensor):
        return {}
    weight = weight.detach().float()
    if head.reads == ("target", "observation"):
        d = target_hidden.shape[-1]
        return {
            "target_term": target_hidden.float() @ weight[:, :d].T,
            "observation_term": observation_hidden.float() @ weight[:, d:].T,
        }
    return {"observation_term": observation_hidden.float() @ weight.T}


def _mean(values: np.ndarray) -> list[float]:
    return [float(v) for v in values.mean(axis=0)] if len(values) else [float("nan")] * values.shape[1]


def target_reading_summary(
    frames: Mapping[str, np.ndarray], in_view: np.ndarray, max_range: float = 3.0
) -> dict[str, Any]:
    """Summaries of the :data:`READINGS` of one model's frames (bool ``in_view`` per frame: the target in
    the camera's cone within ``max_range`` metres).

    Returns:
        ``{"attention_to_target": {"all", "in_view", "out_of_view", "x_uniform"}: one value per block}``
        (mean weight over those frames; ``x_uniform``: mean of weight x number of keys, over all frames), and
        with a linear head ``{"head_terms": {"observation_term_sd": [A] (over frames), and with THSC
        "target_term_mean": [A], "target_term_sd": [A] (over trajectories: the term is constant within
        one)}}``; with a swapped target ``{"target_swap": {"change", "change_in_view": mean |action with the
        swapped target - with its own| [A], "own_sd": [A], "edge_steps", "expert_toward", "own_toward",
        "swapped_toward"}}`` (the turns towards the target at the edge of the view,
        :func:`.actions.edge_of_view_turns` within ``max_range``); action dimensions as the dataset's (linear,
        angular).
    """
    summary: dict[str, Any] = {}
    if "attention_to_target" in frames:
        weights = frames["attention_to_target"]
        summary["attention_to_target"] = {
            "all": _mean(weights),
            "in_view": _mean(weights[in_view]),
            "out_of_view": _mean(weights[~in_view]),
            "x_uniform": _mean(weights * frames["attention_keys"][:, None]),
        }
    if "observation_term" in frames:
        terms: dict[str, list[float]] = {
            "observation_term_sd": [float(v) for v in frames["observation_term"].std(axis=0)]
        }
        if "target_term" in frames:
            _, first = np.unique(frames["trajectory"], return_index=True)
            per_target = frames["target_term"][first]
            terms["target_term_mean"] = [float(v) for v in per_target.mean(axis=0)]
            terms["target_term_sd"] = [float(v) for v in per_target.std(axis=0)]
        summary["head_terms"] = terms
    if "action_swapped" in frames:
        summary["target_swap"] = _swap_summary(frames, in_view, max_range)
    return summary


def _swap_summary(frames: Mapping[str, np.ndarray], in_view: np.ndarray, max_range: float) -> dict[str, Any]:
    from navformer_rl.evaluation.diagnose.actions import edge_of_view_turns

    own, swapped = frames["action_own"], frames["action_swapped"]
    change = np.abs(swapped - own)
    turns = {
        name: edge_of_view_turns(
            actions[:, 1], frames["action"][:, 1], frames["pose"], frames["target"], max_range
        )
        for name, actions in (("own", own), ("swapped", swapped))
    }
    return {
        "change": _mean(change),
        "change_in_view": _mean(change[in_view]),
        "own_sd": [float(v) for v in own.std(axis=0)],
        "edge_steps": turns["own"]["steps"],
        "expert_toward": turns["own"]["expert_toward"],
        "own_toward": turns["own"]["predicted_toward"],
        "swapped_toward": turns["swapped"]["predicted_toward"],
    }


def _values(values: list[float], digits: int = 3) -> str:
    return ", ".join("n/a" if v != v else f"{v:.{digits}f}" for v in values)


def target_reading_markdown(summaries: Mapping[str, Mapping[str, Any]]) -> str:
    """Up to three tables over the models of ``{label: target_reading_summary(...)}``: the attention to the
    target token per block, THSC's target term beside the observation term (models with THSC), and the
    actions with a swapped target (each table over the models that have its reading)."""
    lines: list[str] = []
    attention = [(k, s["attention_to_target"]) for k, s in summaries.items() if "attention_to_target" in s]
    if attention:
        lines += [
            "Attention of the token the action head reads to the target token, per transformer block "
            "(mean weight; x uniform: weight x number of keys):\n",
            "| model | all frames | target in view | target not in view | x uniform |",
            "|---|---|---|---|---|",
        ]
        for label, att in attention:
            lines.append(
                f"| {label} | {_values(att['all'])} | {_values(att['in_view'])} | "
                f"{_values(att['out_of_view'])} | {_values(att['x_uniform'], 2)} |"
            )
    thsc = [
        (label, s["head_terms"])
        for label, s in summaries.items()
        if "target_term_mean" in s.get("head_terms", {})
    ]
    if thsc:
        lines += [
            ("\n" if lines else "")
            + "THSC's head, tanh(W_g h_g + W_o h_o + b): its target term W_g h_g over the held-out targets "
            "against its observation term W_o h_o over frames (linear, angular):\n",
            "| model | W_g h_g mean | W_g h_g sd over targets | W_o h_o sd over frames |",
            "|---|---|---|---|",
        ]
        for label, terms in thsc:
            lines.append(
                f"| {label} | {_values(terms['target_term_mean'])} | {_values(terms['target_term_sd'], 4)} | "
                f"{_values(terms['observation_term_sd'])} |"
            )
    swaps = [(label, s["target_swap"]) for label, s in summaries.items() if "target_swap" in s]
    if swaps:
        lines += [
            ("\n" if lines else "")
            + "Each trajectory's target image swapped for another target's (the object the robot drives to "
            "is then not the one sought): mean |change| of the action (linear, angular), and the share of "
            "turns towards that object at the edge of the view:\n",
            "| model | change, all frames | change, target in view | action sd | edge-of-view steps | "
            "turns towards it: expert / own target / swapped target |",
            "|---|---|---|---|---|---|",
        ]
        for label, swap in swaps:
            toward = " / ".join(
                "n/a" if swap[k] is None else f"{100 * swap[k]:.1f} %"
                for k in ("expert_toward", "own_toward", "swapped_toward")
            )
            lines.append(
                f"| {label} | {_values(swap['change'])} | {_values(swap['change_in_view'])} | "
                f"{_values(swap['own_sd'])} | {swap['edge_steps']:,} | {toward} |"
            )
    return "\n".join(lines) + "\n"
