"""``NavFormerPolicy``: closed-loop NavFormer for ``MultiRobotNavEnv`` (and other envs) with a KV cache."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import Tensor

from navformer_rl.modules.decoding.incremental import (
    IncrementalNavFormer,
    check_window_steps,
    use_native_kernel,
)
from navformer_rl.modules.inputs import MissingKeyError
from navformer_rl.modules.models.navformer import NavFormerModel

POLICY_IN_KEYS: tuple[str, ...] = ("pixels", "target_pixels", "step_count", "reward", "is_init")
"""What :class:`NavFormerPolicy` reads, in the order of its ``in_keys``; the last three are optional."""
OPTIONAL_POLICY_IN_KEYS = ("step_count", "reward", "is_init")
DEFAULT_POLICY_KEYS: dict[str, NestedKey | None] = {
    "pixels": ("agents", "pixels"),
    "target_pixels": ("agents", "target_pixels"),
    "step_count": ("agents", "step_count"),
    "reward": ("agents", "reward"),
    "is_init": "is_init",
    "action": ("agents", "action"),
}
"""The policy's keys for ``MultiRobotNavEnv`` (its defaults), by name (``set_keys``)."""
SINGLE_ROBOT_POLICY_KEYS: dict[str, NestedKey | None] = {
    "pixels": "pixels",
    "target_pixels": "target_pixels",
    "step_count": "step_count",
    "reward": None,
    "is_init": "is_init",
    "action": "action",
}
"""The keys for the single-robot TorchRL env (``make_torchrl_target_nav_env``, root keys) with ``StepCounter``
and ``InitTracker`` (``navformer_rl.envs.policy_transforms.add_policy_transforms``):
``NavFormerPolicy(model).set_keys(**SINGLE_ROBOT_POLICY_KEYS)``."""


class NavFormerPolicy(TensorDictModuleBase):
    """Drive every robot of a batch with one ``NavFormerModel``, one timestep per call (paper §IV, §VII).

    Reads (defaults for ``MultiRobotNavEnv``, group ``"agents"``; ``R`` = robots = product of the leading
    dims, so ``[A]``, ``[E, A]`` for batched envs, or ``[]`` for a single-robot env with root keys):

    - ``("agents", "pixels")`` uint8 ``[*R, 84, 84, 3]`` - current observation o_t;
    - ``("agents", "target_pixels")`` uint8 ``[*R, 84, 84, 3]`` - target image g;
    - ``("agents", "step_count")`` int64 ``[*R, 1]`` (optional) - 0 right after a reset: that robot's
      context is cleared and its R-hat restarts at ``initial_return_to_go``;
    - ``"is_init"`` bool (optional; TorchRL's ``InitTracker`` transform) - True right after a reset, the
      same as ``step_count == 0``; shaped ``[*E, 1]`` for E envs, it applies to every robot of an env
      (so a single-robot ``GymEnv`` without ``step_count`` gets its resets from ``InitTracker``);
    - ``("agents", "reward")`` float ``[*R, 1]`` (optional) - reward received at the previous step:
      ``R-hat_t = R-hat_{t-1} - r_{t-1}`` (DT conditioning, R-hat_1 = 1). A missing key counts as 0.

    Writes ``("agents", "action")`` float32 ``[*R, 2]`` in [-1, 1].

    Keys, as on TorchRL modules: ``in_keys`` are the keys read, in the order ``[pixels, target_pixels,
    step_count, reward, is_init]`` (the last three optional), ``out_keys`` ``[action]``; both are constructor
    arguments and assignable. An ``in_keys`` list is taken in order for what the policy reads (all five for a
    new policy), those past its end then not read; a dict sets them by name. Or name them with
    ``set_keys(pixels=..., target_pixels=..., step_count=..., reward=..., is_init=..., action=...)`` (None:
    not read), as TorchRL's losses do; the former keywords ``pixels_key=``, ``target_pixels_key=``,
    ``step_count_key=``, ``reward_key=``, ``action_key=``, ``is_init_key=`` keep working.
    ``SINGLE_ROBOT_POLICY_KEYS`` are the single-robot env's.
    A missing ``pixels`` / ``target_pixels`` is a ``MissingKeyError`` naming it and ``set_keys``.

    Env transforms: the resets come from ``step_count`` or ``is_init``. ``MultiRobotNavEnv`` has
    ``("agents", "step_count")``; TorchRL's ``Collector`` still looks for ``"is_init"`` (``InitTracker``) and
    warns without it. ``navformer_rl.envs.policy_transforms.add_policy_transforms(env, policy)`` appends what
    an env lacks (``InitTracker``, and ``StepCounter`` for a ``step_count`` key the env does not have).

    Context: the target token, then per step R-hat, e^s, e^ca, a; each call adds one timestep through the
    KV cache (``IncrementalNavFormer``). Past ``context_steps`` timesteps (None, the default: the model's
    whole context, ``config.context_tokens`` = 1024 tokens = 256 steps, 341 for DT) the oldest whole timestep
    leaves the window and the target token stays (streaming window, see ``docs/model.md``). A shorter
    ``context_steps`` is an inference-time option, not the paper's (``docs/deviations.md``). Without
    ``step_count`` in the input, state is cleared by ``reset()``, when the number of robots changes, or never
    otherwise.

    In ``env.rollout``: TorchRL's ``step_mdp`` drops rewards from the next input, so R-hat stays at its
    initial value there unless the env (or a transform) exposes the reward as an observation. With the
    paper's reward (1 only on the success step, after which the robot is done) this changes nothing
    before success. A model in training mode is switched to eval mode for the call and back after it,
    so the policy can evaluate the model being trained (dropout stays on for the training loss).

    Weights: autograd-visible updates (optimizers, ``load_state_dict``) reach the decoder's derived tables
    at once. Updates that no version counter shows (TorchRL's ``update_policy_weights_`` writes through
    ``.data``; ``to_module`` swaps parameters) are found by comparing the weights with a copy whenever a
    robot starts an episode, and then the tables are rebuilt for every robot of the batch (those in the
    middle of an episode keep their KV cache, computed with the old weights). Pickling / ``copy.deepcopy``
    leave out the decoding state: a copy starts new episodes on its own weights.

    native: run the transformer step through the compiled CPU kernel (``IncrementalNavFormer``'s
    ``native``): None uses it where it builds and runs (a CPU decoder; ``NAVFORMER_NATIVE=0`` turns it
    off), True requires it, False keeps the torch path. Both give the same actions up to float rounding.

    context_steps: the timesteps the policy attends to (see Context above), an int from 1 to
    ``config.window_steps``; None (default) is all of them. Changing it starts new episodes.
    """

    def __init__(
        self,
        model: NavFormerModel,
        *,
        initial_return_to_go: float = 1.0,
        in_keys: Sequence[NestedKey] | Mapping[str, NestedKey | None] | None = None,
        out_keys: Sequence[NestedKey] | None = None,
        pixels_key: NestedKey = ("agents", "pixels"),
        target_pixels_key: NestedKey = ("agents", "target_pixels"),
        step_count_key: NestedKey | None = ("agents", "step_count"),
        reward_key: NestedKey | None = ("agents", "reward"),
        action_key: NestedKey = ("agents", "action"),
        is_init_key: NestedKey | None = "is_init",
        native: bool | None = None,
        context_steps: int | None = None,
    ) -> None:
        super().__init__()
        self.model = model
        self.native = native
        check_window_steps(context_steps, model.config.window_steps, "context_steps")
        self.context_steps = context_steps
        self.initial_return_to_go = float(initial_return_to_go)
        given = {
            "pixels": pixels_key,
            "target_pixels": target_pixels_key,
            "step_count": step_count_key,
            "reward": reward_key,
            "is_init": is_init_key,
            "action": action_key,
        }
        changed = [f"{name}_key" for name, key in given.items() if key != DEFAULT_POLICY_KEYS[name]]
        if changed and (in_keys is not None or out_keys is not None):
            raise ValueError(
                f"NavFormerPolicy: pass the keys either as in_keys= / out_keys= or as {changed}, not both"
            )
        self._keys: dict[str, NestedKey | None] = dict(given)
        if in_keys is not None:
            self.in_keys = in_keys
        if out_keys is not None:
            self.out_keys = out_keys
        self._decoder: IncrementalNavFormer | None = None
        self._weights_seen: tuple[list[Tensor], list[Tensor]] | None = None  # see _weights_changed
        self._return_to_go: Tensor | None = None
        self._prev_action: Tensor | None = None

    # -- keys -------------------------------------------------------------------------------------------
    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys read, in the order of :data:`POLICY_IN_KEYS` (those not read left out)."""
        return [self._keys[name] for name in POLICY_IN_KEYS if self._keys[name] is not None]

    @in_keys.setter
    def in_keys(self, keys: Sequence[NestedKey] | Mapping[str, NestedKey | None]) -> None:
        if isinstance(keys, Mapping):
            unknown = sorted(set(keys) - set(POLICY_IN_KEYS))
            if unknown:
                raise ValueError(
                    f"NavFormerPolicy.in_keys: unknown names {unknown}; expected {list(POLICY_IN_KEYS)}"
                )
            named = dict(keys)
        else:
            keys = list(keys)
            read = [name for name in POLICY_IN_KEYS if self._keys[name] is not None]
            if not 2 <= len(keys) <= len(read):
                raise ValueError(
                    f"NavFormerPolicy.in_keys={keys!r}: expected 2 to {len(read)} keys, taken in order for "
                    f"what it reads, {read} (those past the list's end are then not read); "
                    "set_keys(name=key) names them one by one"
                )
            named = dict.fromkeys(read[len(keys) :]) | dict(zip(read, keys))
        self.set_keys(**named)

    @property
    def out_keys(self) -> list[NestedKey]:
        """``[action]``: where the actions are written."""
        return [self._keys["action"]]

    @out_keys.setter
    def out_keys(self, keys: Sequence[NestedKey]) -> None:
        keys = list(keys)
        if len(keys) != 1:
            raise ValueError(
                f"NavFormerPolicy.out_keys={keys!r}: expected one key, where the actions are written"
            )
        self.set_keys(action=keys[0])

    def set_keys(self, **keys: NestedKey | None) -> NavFormerPolicy:
        """Set keys by name - ``pixels``, ``target_pixels``, ``step_count``, ``reward``, ``is_init``
        (None: not read), ``action`` - as TorchRL's losses do; returns the policy."""
        unknown = sorted(set(keys) - set(DEFAULT_POLICY_KEYS))
        if unknown:
            raise ValueError(
                f"NavFormerPolicy.set_keys: {unknown} are not keys of the policy; expected some of "
                f"{list(DEFAULT_POLICY_KEYS)}"
            )
        for name in ("pixels", "target_pixels", "action"):
            if name in keys and keys[name] is None:
                raise ValueError(f"NavFormerPolicy.set_keys: {name} is required, got None")
        self._keys.update(keys)
        return self

    @property
    def pixels_key(self) -> NestedKey:
        return self._keys["pixels"]

    @property
    def target_pixels_key(self) -> NestedKey:
        return self._keys["target_pixels"]

    @property
    def step_count_key(self) -> NestedKey | None:
        return self._keys["step_count"]

    @property
    def reward_key(self) -> NestedKey | None:
        return self._keys["reward"]

    @property
    def is_init_key(self) -> NestedKey | None:
        return self._keys["is_init"]

    @property
    def action_key(self) -> NestedKey:
        return self._keys["action"]

    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    def describe(self, device: torch.device | None = None) -> dict[str, str]:
        """What evaluation records about how this policy decodes on ``device`` (default: its model's):
        ``{"transformer_step": "native" | "torch"}``, the compiled kernel or the torch path (equal results up
        to float rounding). Raises ``ValueError`` when ``native=True`` and the kernel cannot run there."""
        native = use_native_kernel(self.native, self.model, device if device is not None else self.device)
        return {"transformer_step": "native" if native else "torch"}

    def reset(self) -> None:
        """Forget every robot's episode (the next call starts new episodes with a new decoder, whose
        derived weights are rebuilt from the model)."""
        self._decoder = None

    def __getstate__(self) -> dict:
        """Pickling and ``copy.deepcopy`` leave out the decoding state (the KV cache and the tables derived
        from the weights): a copy starts new episodes on its own weights. Collectors that spawn workers
        (``MultiSyncCollector``) and ``torch.save(policy)`` rely on it."""
        state = super().__getstate__()  # nn.Module's: a copy, without a compiled call
        state.update(_decoder=None, _return_to_go=None, _prev_action=None, _weights_seen=None)
        return state

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if not self.model.training:
            return self._act(tensordict)
        self.model.eval()
        try:
            return self._act(tensordict)
        finally:
            self.model.train()

    def _input(self, tensordict: TensorDictBase, name: str) -> Tensor:
        key = self._keys[name]
        value = tensordict.get(key, None)
        side = self.model.config.image_size
        if value is None:
            keys = sorted(map(str, tensordict.keys(True, True)))
            raise MissingKeyError(
                f"NavFormerPolicy reads {key!r} ({name}: uint8 [..., {side}, {side}, 3]), missing from the "
                f"input tensordict with keys {keys}; point it at your key with policy.set_keys({name}=...) "
                "(e.g. set_keys(**SINGLE_ROBOT_POLICY_KEYS) for the single-robot env)"
            )
        if value.dtype != torch.uint8:
            raise ValueError(
                f"NavFormerPolicy: {key!r} must be uint8 HWC images [..., {side}, {side}, 3], got "
                f"{value.dtype} {list(value.shape)}; for TorchRL's float CHW images (ToTensorImage) append "
                "navformer_rl.envs.policy_transforms.ToUint8Image to the env"
            )
        return value

    def _act(self, tensordict: TensorDictBase) -> TensorDictBase:
        pixels = self._input(tensordict, "pixels")
        lead = pixels.shape[:-3]
        robots = int(torch.Size(lead).numel())
        side = self.model.config.image_size
        if pixels.shape[-3:] != (side, side, 3):
            raise ValueError(
                f"{self.pixels_key!r}: expected frames [..., {side}, {side}, 3] (the model's image_size), "
                f"got shape {tuple(pixels.shape)}"
            )
        target = self._input(tensordict, "target_pixels")
        if target.shape != pixels.shape:
            raise ValueError(
                f"{self.target_pixels_key!r}: expected the shape of {self.pixels_key!r} "
                f"{tuple(pixels.shape)} (one target image per robot), got {tuple(target.shape)}"
            )
        pixels = pixels.reshape(robots, *pixels.shape[-3:])
        target = target.reshape(robots, *pixels.shape[-3:])
        device = self.device  # looked up once per call: parameters() is not free at batch 1
        new_episode = self._new_episode_flags(tensordict, robots, device)
        window = check_window_steps(self.context_steps, self.model.config.window_steps, "context_steps")
        if (
            self._decoder is None
            or self._decoder.batch != robots
            or self._decoder.device != device
            or self._decoder.window_steps != window
        ):
            self._decoder = IncrementalNavFormer(
                self.model, robots, device=device, native=self.native, window_steps=window
            )
            self._remember_weights()
            self._return_to_go = torch.full((robots, 1), self.initial_return_to_go, device=device)
            self._prev_action = torch.zeros(robots, self.model.config.action_dim, device=device)
            new_episode = torch.ones(robots, dtype=torch.bool, device=device)
        elif bool(new_episode.any()) and self._weights_changed():
            # weight updates no version counter shows: TorchRL's weight sync writes through `.data`,
            # `to_module` swaps parameters
            self._decoder.refresh()
            self._remember_weights()
        reward = self._reward(tensordict, robots, device)
        self._return_to_go = torch.where(
            new_episode[:, None],
            torch.full_like(self._return_to_go, self.initial_return_to_go),
            self._return_to_go - reward,
        )
        self._decoder.reset(new_episode)
        action = self._decoder.step(target, pixels, self._return_to_go, self._prev_action)
        self._prev_action = action
        out_device = tensordict.device if tensordict.device is not None else pixels.device
        tensordict.set(self.action_key, action.reshape(*lead, -1).to(out_device))
        return tensordict

    def _weights_changed(self) -> bool:
        """Whether the model's parameters / buffers are other tensors or hold other values than at the
        decoder's last (re)build (one ``torch.equal`` per tensor, ~0.3 ms for the paper model on a CPU;
        checked only at steps where a robot starts an episode)."""
        current = [*self.model.parameters(), *self.model.buffers()]
        seen, copies = self._weights_seen
        if len(current) != len(seen) or any(a is not b for a, b in zip(current, seen)):
            return True
        return not all(torch.equal(tensor, copy) for tensor, copy in zip(current, copies))

    def _remember_weights(self) -> None:
        tensors = [*self.model.parameters(), *self.model.buffers()]
        with torch.no_grad():
            self._weights_seen = (tensors, [t.detach().clone() for t in tensors])

    def _new_episode_flags(self, tensordict: TensorDictBase, robots: int, device: torch.device) -> Tensor:
        """bool ``[robots]``: robots whose episode starts at this call
        (``step_count == 0`` or ``is_init``)."""
        flags = torch.zeros(robots, dtype=torch.bool, device=device)
        step_count = None if self.step_count_key is None else tensordict.get(self.step_count_key, None)
        if step_count is not None:
            flags |= (step_count.reshape(robots) == 0).to(device)
        is_init = None if self.is_init_key is None else tensordict.get(self.is_init_key, None)
        if is_init is not None:
            is_init = is_init.reshape(-1).to(device, torch.bool)
            if robots % is_init.numel():
                raise ValueError(
                    f"{self.is_init_key!r}: {is_init.numel()} flags for {robots} robots; expected one per "
                    "env (or per robot)"
                )
            flags |= is_init.repeat_interleave(robots // is_init.numel())
        return flags

    def _reward(self, tensordict: TensorDictBase, robots: int, device: torch.device) -> Tensor:
        reward = None if self.reward_key is None else tensordict.get(self.reward_key, None)
        if reward is None:
            return torch.zeros(robots, 1, device=device)
        return reward.reshape(robots, 1).to(device, torch.float32)
