"""Incremental (one timestep per call) NavFormer decoding with a streaming key/value cache.

Per robot ``b`` the cache holds ``S = 1 + W * tps`` slots (``W = window_steps``, by default
``config.window_steps``: 256 steps of 4 tokens for the paper's 1024-token context): slot 0 is the target
token, then ``W`` groups of ``tps`` slots used as a ring (step ``t`` lives in group ``t mod W``).
``slot_pos[b, s]`` is the token's position in the robot's sequence (-1 = empty); the attention mask is built
from it, so slot order never matters.

The call for step t feeds ``tps`` new tokens: ``[a_{t-1}, R_t, e^s_t, e^ca_t]`` (``[g, R_1, e^s_1, e^ca_1]``
on a robot's first step). When the window is full, step t overwrites step t - W's slots and invalidates
its action slot: the oldest whole timestep leaves, the target token stays. Keys/values of the steps that
remain are kept as computed (a streaming window): the result equals ``NavFormerModel.forward(...,
window_steps=W)`` on the whole episode, and plain causal ``forward`` as long as ``t < W``.

The decoder runs the parameters of the model's parts: ``model.dve`` (the encoders), ``model.transformer``
(``tokens`` as ``StepLayers`` tables, ``gpt`` as ``TransformerStep`` / the native kernel), ``model.head``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from navformer_rl.modules.decoding.fused_encoders import FusedConvEncoders
from navformer_rl.modules.decoding.native import (
    BlockedKVCache,
    NativeTransformerStep,
    native_status,
    native_support,
)
from navformer_rl.modules.decoding.step_layers import StepLayers
from navformer_rl.modules.decoding.transformer_step import TransformerStep
from navformer_rl.modules.models.cnn import ConvEncoder
from navformer_rl.modules.models.gpt import KVCache
from navformer_rl.modules.models.navformer import NavFormerModel
from navformer_rl.modules.models.ops.attention import additive_mask


class IncrementalNavFormer:
    """Streaming decoder state for ``batch`` robots that share one ``NavFormerModel`` (in eval mode).

    Usage: ``dec = IncrementalNavFormer(model, batch)``; every control step
    ``action = dec.step(target_pixels, pixels, return_to_go, prev_action)``; ``dec.reset(robots)`` starts
    new episodes for the robots where ``robots`` (bool ``[batch]``) is True. While every robot is at the same
    step (never reset apart) ``step`` takes a host-side fast path (``_step_shared``, same results).

    Per step at batch 1 every op is tiny, so the step avoids per-op overhead: both paper CNNs run as one
    fused stack (``FusedConvEncoders``, im2col + matmuls for up to 4 robots), the token embeddings and the
    THSC head use precomputed tables (``StepLayers``), and the attention mask is additive. The transformer
    runs through the compiled CPU kernel (``NativeTransformerStep``, ``native/transformer_step.c``, built
    with the system C compiler on first use; ~0.6x the step time at batch 1) or as a loop of plain tensor
    ops (``TransformerStep``): ``native`` True requires the kernel (``ValueError`` with the reason when it
    is unavailable: no compiler, ``NAVFORMER_NATIVE=0``, a GPU decoder, widths not multiples of 16), False
    keeps the torch path, None (default) takes the kernel where it can. Both give the same results up to
    float rounding (tested); ``self.native`` says which one runs.
    Each helper rebuilds its tables when a parameter is updated in place through autograd-visible ops
    (``torch.optim``'s default optimizers, ``load_state_dict``, ``model.to``), so an evaluation between
    optimizer steps stays exact. Not seen: ``p.data`` writes, fused optimizers (``AdamW(fused=True)``),
    ``load_state_dict(..., assign=True)`` and replaced sub-modules - call ``refresh()`` after those.

    ``window_steps``: the streaming window W in timesteps, at most ``config.window_steps`` (the default);
    a shorter one is an inference-time option (``NavFormerPolicy(context_steps=)``, ``docs/model.md``).
    The model must hold float32 parameters; the decoder state is allocated outside inference mode, so
    ``step`` may run under ``torch.inference_mode()`` or ``torch.no_grad()`` alike.
    """

    def __init__(
        self,
        model: NavFormerModel,
        batch: int,
        device: torch.device | str | None = None,
        native: bool | None = None,
        window_steps: int | None = None,
    ) -> None:
        if batch <= 0:
            raise ValueError(f"batch={batch!r}: expected a positive number of robots")
        self.window_steps = check_window_steps(window_steps, model.config.window_steps)
        dtype = next(model.parameters()).dtype
        if dtype != torch.float32:
            raise ValueError(
                f"IncrementalNavFormer decodes float32 models; this one holds {dtype} parameters"
            )
        device = torch.device(device) if device is not None else next(model.parameters()).device
        self.native = use_native_kernel(native, model, device)
        with torch.inference_mode(False), torch.no_grad():
            self._allocate(model, batch, device, dtype)
        self.refresh()

    def _allocate(self, model: NavFormerModel, batch: int, device: torch.device, dtype: torch.dtype) -> None:
        """The decoder state: KV cache, slot positions, step counters and the masks (see ``__init__``)."""
        config = model.config
        self.model = model
        self.batch = batch
        self.device = device
        self.dtype = dtype
        self.tokens_per_step = config.tokens_per_step
        slots = 1 + self.window_steps * self.tokens_per_step
        cache_type = BlockedKVCache if self.native else KVCache
        self.cache = cache_type.empty(
            config.n_blocks, batch, config.n_heads, slots, config.d_head, device, dtype
        )
        self.slot_pos = torch.full((batch, slots), -1, dtype=torch.long, device=self.device)
        self._steps_done = torch.zeros(batch, dtype=torch.long, device=self.device)
        self.target_hidden = torch.zeros(batch, config.d_embed, dtype=dtype, device=self.device)
        self._offsets = torch.arange(self.tokens_per_step - 1, device=self.device)
        # Fast path (every robot at the same step, e.g. all reset together): ``_shared_step`` is the number
        # of steps done, on the host (None once robots diverge); ``slot_pos`` and ``_steps_done`` are then
        # left alone and only written when the robots diverge (``_leave_shared_path``). Until the ring wraps
        # (t < W) slot s holds position s, so the mask is the bottom-right-aligned causal mask: a column slice
        # of ``_causal_bias`` (additive ``[1, 1, tps, S]``, query i may attend slot s
        # iff s <= S - tps - 1 + i).
        self._shared_step: int | None = 0
        query = torch.arange(self.tokens_per_step, device=self.device)
        causal = (
            torch.arange(slots, device=self.device)[None, :]
            <= (slots - self.tokens_per_step - 1 + query)[:, None]
        )
        self._causal_bias = additive_mask(causal[None, None], dtype)
        # Past the wrap (t >= W) every slot is valid except step t's action slot, and the only masked entries
        # are those of the newest step: its ``tps`` slots get the same pattern as the last ``tps`` columns of
        # ``_causal_bias`` (token j may see the step's tokens up to itself). ``_wrapped_bias`` holds that
        # pattern at the current group's columns (``_wrapped_at``) and zeros elsewhere.
        self._wrapped_bias = torch.zeros_like(self._causal_bias)
        self._wrapped_at: int | None = None

    def refresh(self) -> None:
        """Rebuild the fast-path helpers from the model's current sub-modules and parameters.

        Needed only after updates the helpers cannot see (see the class docstring); the decoding state
        (cache, steps) is kept.
        """
        model = self.model
        self._layers = StepLayers(model)
        self._transformer = (NativeTransformerStep if self.native else TransformerStep)(model.transformer.gpt)
        encoders = [encoder for _, encoder in model.dve.observation_encoders()]
        self._fused_encoders = (
            FusedConvEncoders(*encoders)
            if len(encoders) == 2 and all(isinstance(e, ConvEncoder) for e in encoders)
            else None
        )

    @property
    def steps_done(self) -> Tensor:
        """long ``[batch]``: the steps each robot has decoded since its last reset."""
        if self._shared_step is not None:
            return torch.full_like(self._steps_done, self._shared_step)
        return self._steps_done

    def reset(self, robots: Tensor | None = None) -> None:
        """Forget the episode of the robots where ``robots`` (bool ``[batch]``) is True (all if None)."""
        if robots is None or bool(robots.all()):
            self._shared_step = 0  # slot_pos / _steps_done are written when the robots diverge
        elif bool(robots.any()):
            self._leave_shared_path()  # the robots' steps now differ: general path
            self._steps_done[robots] = 0
            self.slot_pos[robots] = -1

    def _leave_shared_path(self) -> None:
        """Write the shared path's state into ``slot_pos`` / ``_steps_done`` for the general path."""
        if self._shared_step is None:
            return
        self.slot_pos.copy_(self.shared_slot_positions(self._shared_step))
        self._steps_done.fill_(self._shared_step)
        self._shared_step = None

    def shared_slot_positions(self, steps: int) -> Tensor:
        """long ``[S]``: every slot's sequence position (-1 = empty) after ``steps`` steps from a reset.

        Slot 0 holds the target (position 0); the steps ``s`` still in the window (the last W) hold R_s and
        the observation tokens at positions ``s * tps + 1 ..`` in their group's first ``tps - 1`` slots, and
        a_s at position ``(s + 1) * tps`` in the group's last slot once step ``s + 1`` has fed it (the newest
        step's action slot is empty). The same as the general path's bookkeeping (tested).
        """
        tps, window = self.tokens_per_step, self.window_steps
        positions = torch.full((self.slot_pos.shape[1],), -1, dtype=torch.long, device=self.device)
        if steps == 0:
            return positions
        positions[0] = 0
        kept = torch.arange(max(0, steps - window), steps, device=self.device)  # steps in the window
        group = 1 + (kept % window) * tps
        positions[group[:, None] + self._offsets] = kept[:, None] * tps + 1 + self._offsets
        acted = kept[:-1]  # a_s is fed by step s + 1
        positions[group[:-1] + tps - 1] = (acted + 1) * tps
        return positions

    def encode_observations(self, pixels: Tensor) -> Tensor:
        """``[B, H, W, 3]`` u8 -> ``[B, n_enc, d]``; both paper CNNs run as one fused stack (same values)."""
        if self._fused_encoders is not None:
            return self._fused_encoders(pixels)
        return self.model.dve.encode_observations(pixels)

    @torch.inference_mode()
    def step(
        self, target_pixels: Tensor, pixels: Tensor, return_to_go: Tensor, prev_action: Tensor
    ) -> Tensor:
        """Decode one timestep for every robot.

        Args:
            target_pixels: uint8 ``[B, H, W, 3]`` (read only for robots at their first step).
            pixels: uint8 ``[B, H, W, 3]`` - the current observation o_t.
            return_to_go: float ``[B, 1]`` - R-hat_t.
            prev_action: float ``[B, A]`` - a_{t-1} (ignored for robots at their first step).

        Returns:
            action: float ``[B, A]`` in [-1, 1], a-hat_t.
        """
        model = self.model
        if model.training:
            raise ValueError("IncrementalNavFormer.step: call model.eval() first (dropout must be off)")
        if pixels.shape[0] != self.batch:
            raise ValueError(f"pixels: expected {self.batch} robots, got shape {tuple(pixels.shape)}")
        if self._shared_step is not None:
            return self._step_shared(target_pixels, pixels, return_to_go, prev_action)
        tps, window = self.tokens_per_step, self.window_steps
        t = self._steps_done
        first = t == 0
        any_first = bool(first.any())
        target = None
        if any_first:
            target = model.dve.encode_target(target_pixels[first.to(target_pixels.device)].to(self.device))
        tokens = self._layers.tokens(
            prev_action.to(self.device),
            return_to_go.to(self.device),
            self.encode_observations(pixels.to(self.device)),
            t.clamp(max=model.config.max_timestep),
            target,
            first,
        )

        # slots and sequence positions of the new tokens
        group = 1 + (t % window) * tps
        prev_action_slot = 1 + ((t - 1) % window) * tps + tps - 1
        write_index = torch.cat(
            [torch.where(first, 0, prev_action_slot)[:, None], group[:, None] + self._offsets], 1
        )
        new_pos = torch.cat(
            [torch.where(first, 0, t * tps)[:, None], (1 + t * tps)[:, None] + self._offsets], 1
        )
        if any_first:
            self.slot_pos[first] = -1
        self.slot_pos.scatter_(1, (group + tps - 1)[:, None], -1)  # a_{t-W} leaves with step t-W
        self.slot_pos.scatter_(1, write_index, new_pos)
        used = min(self.slot_pos.shape[1], 1 + tps * (int(t.max()) + 1))  # slots beyond are still empty
        slot_pos = self.slot_pos[:, None, :used]
        allowed = ((slot_pos >= 0) & (slot_pos <= new_pos[:, :, None])).unsqueeze(1)

        dtype = self.dtype
        hidden = self._transformer(tokens.to(dtype), additive_mask(allowed, dtype), self.cache, write_index)
        self.target_hidden = torch.where(first[:, None], hidden[:, 0], self.target_hidden)
        action = self._layers.action(self.target_hidden, hidden[:, tps - 1])
        self._steps_done += 1
        return action

    def _wrapped_mask(self, group: int) -> Tensor:
        """Additive ``[1, 1, tps, S]`` mask of a shared step past the wrap whose new step fills ``group``.

        Equals the mask built from ``slot_pos`` (``(slot_pos >= 0) & (slot_pos <= new_pos)``): every slot is
        valid and older than the new tokens except the group's own ``tps`` slots, which get the causal
        pattern of ``_causal_bias``'s last ``tps`` columns. Two small copies instead of a comparison of the
        whole window.
        """
        tps = self.tokens_per_step
        if self._wrapped_at != group:
            if self._wrapped_at is not None:
                self._wrapped_bias[..., self._wrapped_at : self._wrapped_at + tps] = 0.0
            self._wrapped_bias[..., group : group + tps] = self._causal_bias[..., -tps:]
            self._wrapped_at = group
        return self._wrapped_bias

    def _step_shared(
        self, target_pixels: Tensor, pixels: Tensor, return_to_go: Tensor, prev_action: Tensor
    ) -> Tensor:
        """``step`` when every robot is at step ``t = self._shared_step`` (same arguments and result).

        Same maths as the general path with the bookkeeping done on the host: the first token is the
        target token or the action token (not both), the new tokens' slots are one contiguous ``slice``
        (except when the ring wraps: a_{t-1} sits in the last slot), the mask is a view of ``_causal_bias``
        before the ring wraps and ``_wrapped_mask`` after, and ``slot_pos`` / ``_steps_done`` are left for
        ``_leave_shared_path`` to write when the robots diverge. No host synchronisation.
        """
        model = self.model
        tps, window, slots = self.tokens_per_step, self.window_steps, self.slot_pos.shape[1]
        t = self._shared_step
        first = t == 0
        target = model.dve.encode_target(target_pixels.to(self.device)) if first else None
        tokens = self._layers.tokens(
            prev_action.to(self.device),
            return_to_go.to(self.device),
            self.encode_observations(pixels.to(self.device)),
            min(t, model.config.max_timestep),
            target,
        )

        group = 1 + (t % window) * tps
        first_slot = 0 if first else 1 + ((t - 1) % window) * tps + tps - 1
        if first_slot == group - 1:
            write_index: Tensor | slice = slice(first_slot, first_slot + tps)
        else:  # the ring wrapped: a_{t-1} sits in the last slot, the rest at the start
            slots_written = [first_slot, *range(group, group + tps - 1)]
            write_index = torch.tensor(slots_written, device=self.device).expand(self.batch, tps)
        used = min(slots, 1 + tps * (t + 1))
        attn_mask = self._causal_bias[..., slots - used :] if t < window else self._wrapped_mask(group)

        hidden = self._transformer(tokens.to(self.dtype), attn_mask, self.cache, write_index)
        if first:
            self.target_hidden = hidden[:, 0].clone()
        action = self._layers.action(self.target_hidden, hidden[:, tps - 1])
        self._shared_step = t + 1
        return action


def use_native_kernel(native: bool | None, model: NavFormerModel, device: torch.device) -> bool:
    """Whether a decoder of ``model`` on ``device`` runs its transformer step through the compiled kernel
    (``native`` None: when it can; see ``IncrementalNavFormer``).

    Raises:
        ValueError: ``native=True`` but the kernel is unavailable or cannot run this model / device.
    """
    if native is False:
        return False
    status = native_status()
    reason = None if status.available else status.reason
    if reason is None and device.type != "cpu":
        reason = f"the kernel runs on the CPU, the decoder on {device}"
    if reason is None:
        reason = native_support(model.transformer.gpt)
    if reason is not None and native:
        raise ValueError(f"IncrementalNavFormer(native=True): {reason}")
    return reason is None


def check_window_steps(window_steps: int | None, most: int, name: str = "window_steps") -> int:
    """``window_steps`` (None: ``most``, the model's whole context in timesteps), checked: an int in
    ``[1, most]``; ValueError naming it (as ``name``) and the value otherwise."""
    if window_steps is None:
        return most
    if isinstance(window_steps, bool) or not isinstance(window_steps, int) or not 1 <= window_steps <= most:
        raise ValueError(
            f"{name}={window_steps!r}: expected a whole number of timesteps from 1 to {most} (the "
            "model's context, config.context_tokens // tokens_per_step), or None for all of it"
        )
    return window_steps
