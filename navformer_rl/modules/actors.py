"""TensorDict modules of NavFormer's parts and their composition, the training actor (teacher forcing).

Each part is a ``TensorDictModule`` around the plain ``nn.Module`` of ``navformer_rl.modules.models``;
keys are renamed through ``in_keys`` / ``out_keys``. The defaults chain into ``make_navformer_actor``::

    dve_module          pixels, target_pixels, mask -> ("embed", "static"), ("embed", "general"),
                                                       ("embed", "target")
    transformer_module  ("embed", "target"), ("embed", "static"), ("embed", "general"), return_to_go,
                        action, step, mask -> ("hidden", "target"), ("hidden", "observation"),
                                              ("hidden", "tokens")
    head_module         ("hidden", "target"), ("hidden", "observation"), mask -> action_pred
                        (and action_logits with the opt-in ``BinnedActionHead``)

(an ablation with one encoder has one ``("embed", name)`` key; ``ObservationHead`` reads no
``("hidden", "target")``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential, dispatch
from tensordict.utils import NestedKey

from navformer_rl.modules.inputs import check_trajectory_steps, check_unmasked_padding, require_keys
from navformer_rl.modules.models.dve import DualVisualEncoder
from navformer_rl.modules.models.heads import ActionHead, BinnedActionHead
from navformer_rl.modules.models.navformer import NavFormerModel
from navformer_rl.modules.models.transformer import HIDDEN_NAMES, CausalTransformer
from navformer_rl.utils.length_groups import length_sorted_groups

NAVFORMER_IN_KEYS: tuple[str, ...] = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")
"""Default in_keys of ``make_navformer_actor``, in the order of ``NavFormerModel.forward``'s arguments."""
NAVFORMER_OUT_KEYS: tuple[str, ...] = ("action_pred",)
ACTION_LOGITS_KEY = "action_logits"
"""What a ``BinnedActionHead`` writes beside ``action_pred``: float32 logits ``[N, T, A, K]``
(``ActionBinLoss`` reads them)."""
EMBED_KEY = "embed"
"""Parent key of the DVE's outputs: ``("embed", "static")``, ``("embed", "general")``,
``("embed", "target")``."""
HIDDEN_KEY = "hidden"
"""Parent key of the causal transformer's outputs: ``("hidden", name)`` for name in ``HIDDEN_NAMES``."""


INPUT_MEANINGS: dict[str, str] = {
    "pixels": "uint8 frames [N, T, 84, 84, 3]",
    "target_pixels": "uint8 target images [N, 84, 84, 3]",
    "return_to_go": "float R-hat [N, T, 1]",
    "action": "float actions [N, T, 2], teacher forcing",
    "step": "int64 absolute timesteps [N, T]",
    "mask": "bool [N, T], True on valid steps",
    "target_embedding": "the DVE's target embedding e_g [N, d]",
    "static": "the DVE's e^s [N, T, d]",
    "general": "the DVE's e^ca [N, T, d]",
    "target_hidden": "the transformer's h_g [N, T, d]",
    "observation_hidden": "the transformer's h_o [N, T, d]",
    "tokens_hidden": "the transformer's token hidden states [N, T, tps, d]",
}
"""What each input of the parts holds, for the errors naming a missing key."""
OPTIONAL_INPUTS = ("mask",)
"""The only optional input of a trajectory batch: without it every step counts as valid."""


class CheckedModule(TensorDictModule):
    """A ``TensorDictModule`` whose call first checks its in keys: a missing required key is a
    :class:`~navformer_rl.modules.inputs.MissingKeyError` naming it, what it holds and how to rename it
    (``in_keys=`` of ``maker``), instead of a failure inside the module. ``inputs``: one input name of
    :data:`INPUT_MEANINGS` per in key, in order; ``mask`` may be absent. With ``step_input``, the timesteps
    must be ``[N, T]`` and, without a mask, show no padding (``check_unmasked_padding``)."""

    def __init__(
        self,
        module: torch.nn.Module,
        in_keys: Sequence[NestedKey] | dict[str, NestedKey],
        out_keys: Sequence[NestedKey],
        *,
        inputs: Sequence[str],
        maker: str,
        step_input: bool = False,
        **kwargs,
    ) -> None:
        super().__init__(module, in_keys=in_keys, out_keys=out_keys, **kwargs)
        self.maker = maker
        names = list(inputs)
        self.input_keys = dict(zip(names, self.in_keys, strict=True))
        self.required = {
            key: INPUT_MEANINGS.get(name, f"the input {name!r} of the module")
            for name, key in self.input_keys.items()
            if name not in OPTIONAL_INPUTS
        }
        self.step_input = step_input
        self.rename_hint = f"pass in_keys=[...] to {maker} in the order {names}"

    @dispatch(auto_batch_size=False)
    def forward(self, tensordict: TensorDictBase, *args, **kwargs) -> TensorDictBase:
        require_keys(tensordict, self.required, self.maker, self.rename_hint)
        if self.step_input:
            step_key, mask_key = self.input_keys["step"], self.input_keys["mask"]
            step = tensordict.get(step_key)
            check_trajectory_steps(step, step_key, 0, self.maker, "int64 [N, T]")
            if tensordict.get(mask_key, None) is None:
                check_unmasked_padding(step, mask_key, step_key, self.maker)
        return super().forward(tensordict, *args, **kwargs)


def _checked(keys: Sequence[NestedKey] | None, default: list[NestedKey], what: str) -> list[NestedKey]:
    if keys is None:
        return default
    if len(keys) != len(default):
        raise ValueError(f"{what}={list(keys)!r}: expected {len(default)} keys, in the order of {default}")
    return list(keys)


def dve_module(
    dve: DualVisualEncoder,
    in_keys: Sequence[NestedKey] | None = None,
    out_keys: Sequence[NestedKey] | None = None,
) -> TensorDictModule:
    """``dve`` as a ``TensorDictModule``.

    in_keys (default ``["pixels", "target_pixels", "mask"]``): uint8 frames ``[..., H, W, 3]``, uint8 target
    images ``[B, H, W, 3]`` (or ``[B, T, H, W, 3]``), optional bool mask (a missing key means all valid).
    out_keys (default ``[("embed", name) for name in dve.names] + [("embed", "target")]``): e^s / e^ca
    ``[..., d]`` and e_g.
    """
    default_out: list[NestedKey] = [(EMBED_KEY, name) for name in (*dve.names, "target")]
    return CheckedModule(
        dve,
        in_keys=_checked(in_keys, ["pixels", "target_pixels", "mask"], "in_keys"),
        out_keys=_checked(out_keys, default_out, "out_keys"),
        inputs=["pixels", "target_pixels", "mask"],
        maker="dve_module",
    )


def transformer_module(
    transformer: CausalTransformer,
    in_keys: Sequence[NestedKey] | None = None,
    out_keys: Sequence[NestedKey] | None = None,
) -> TensorDictModule:
    """``transformer`` as a ``TensorDictModule``.

    in_keys (default ``[("embed", "target"), *(("embed", name) for name in observation_names),
    "return_to_go", "action", "step", "mask"]``): e_g, the observation embeddings ``[B, T, d]``, R-hat
    ``[B, T, 1]``, actions ``[B, T, A]``, int64 timesteps ``[B, T]``, optional bool mask ``[B, T]``.
    out_keys (default ``[("hidden", name) for name in HIDDEN_NAMES]``): h_g ``[B, T, d]``, h_o ``[B, T, d]``,
    the token hidden states ``[B, T, tps, d]`` (see ``CausalTransformer``).
    """
    arguments = ["target_embedding", *transformer.observation_names, "return_to_go", "action", "step", "mask"]
    default_in: list[NestedKey] = [
        (EMBED_KEY, "target"),
        *((EMBED_KEY, name) for name in transformer.observation_names),
        "return_to_go",
        "action",
        "step",
        "mask",
    ]
    in_keys = _checked(in_keys, default_in, "in_keys")
    return CheckedModule(
        transformer,
        in_keys=dict(zip(arguments, in_keys, strict=True)),
        out_to_in_map=True,
        out_keys=_checked(out_keys, [(HIDDEN_KEY, name) for name in HIDDEN_NAMES], "out_keys"),
        inputs=arguments,
        maker="transformer_module",
        step_input=True,
    )


def head_module(
    head: ActionHead | BinnedActionHead,
    in_keys: Sequence[NestedKey] | None = None,
    out_keys: Sequence[NestedKey] | None = None,
) -> TensorDictModule:
    """``head`` as a ``TensorDictModule``.

    in_keys (default ``[("hidden", name) for name in head.reads] + ["mask"]``); out_keys (default
    ``["action_pred"]``, and ``"action_logits"`` after it for a ``BinnedActionHead``): float32 actions
    ``[B, T, A]`` in [-1, 1] (logits ``[B, T, A, K]``), 0 on padded steps.
    """
    default_in: list[NestedKey] = [*((HIDDEN_KEY, name) for name in head.reads), "mask"]
    return CheckedModule(
        head,
        in_keys=_checked(in_keys, default_in, "in_keys"),
        out_keys=_checked(out_keys, _head_out_keys(head, NAVFORMER_OUT_KEYS[0]), "out_keys"),
        inputs=[*(f"{name}_hidden" for name in head.reads), "mask"],
        maker="head_module",
    )


def _head_out_keys(head: ActionHead | BinnedActionHead, action_pred: NestedKey) -> list[NestedKey]:
    """What ``head`` writes: ``[action_pred]``, and ``ACTION_LOGITS_KEY`` after it for a
    ``BinnedActionHead``."""
    return [action_pred, ACTION_LOGITS_KEY] if isinstance(head, BinnedActionHead) else [action_pred]


class LengthGroups(TensorDictModuleBase):
    """Run a per-step module on groups of trajectories of similar length, each cropped to its longest one.

    ``LengthGroups(module, groups, mask_key="mask", per_trajectory_keys=())`` reads a tensordict of batch size
    ``[N]`` whose per-step keys are ``[N, T, ...]`` with a right-padded bool mask ``[N, T]``, orders the
    trajectories by valid length, runs ``module`` on ``min(groups, N)`` consecutive groups ``[n_i, T_i, ...]``
    (``T_i`` the group's longest trajectory) and writes every out key back as ``[N, T, ...]``, zeros past
    ``T_i``. For a causal module that ignores padded steps (the transformer and the head) the valid outputs
    are the ones of one padded pass, with the attention and the token work of the padding left out.
    ``per_trajectory_keys``: in keys without a time axis when their value has ``[N, d]`` (the target
    embedding; an ``[N, T, d]`` value is cropped like the rest). Tensordicts of another batch size, a
    missing mask or ``groups=1`` go through ``module`` unchanged.
    """

    def __init__(
        self,
        module: TensorDictModuleBase,
        groups: int,
        mask_key: NestedKey = "mask",
        per_trajectory_keys: Sequence[NestedKey] = (),
    ) -> None:
        super().__init__()
        if not isinstance(groups, int) or groups < 1:
            raise ValueError(f"groups={groups!r}: expected an integer >= 1")
        self.module = module
        self.groups = groups
        self.mask_key = mask_key
        self.per_trajectory_keys = list(per_trajectory_keys)
        self.in_keys = list(module.in_keys)
        self.out_keys = list(module.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        mask = tensordict.get(self.mask_key, None)
        if self.groups == 1 or mask is None or tensordict.batch_dims != 1 or tensordict.shape[0] < 2:
            return self.module(tensordict)
        steps = mask.shape[1]
        groups = length_sorted_groups(mask, self.groups)
        outputs: dict[NestedKey, list[torch.Tensor]] = {key: [] for key in self.out_keys}
        for rows, t in groups:
            part = TensorDict(batch_size=[rows.numel()], device=tensordict.device)
            for key in self.in_keys:
                value = tensordict.get(key, None)
                if value is None:
                    continue
                value = value[rows]
                flat = key in self.per_trajectory_keys and value.dim() == 2
                part.set(key, value if flat else value[:, :t])
            part = self.module(part)
            for key in self.out_keys:
                value = part.get(key)
                outputs[key].append(F.pad(value, (0, 0) * (value.dim() - 2) + (0, steps - t)))
        # the groups hold the rows in length order: one gather puts them back in the batch's order
        back = torch.argsort(torch.cat([rows for rows, _ in groups]))
        for key, values in outputs.items():
            tensordict.set(key, torch.cat(values)[back])
        return tensordict


class NavFormerActor(TensorDictSequential):
    """The ``TensorDictSequential`` of :func:`make_navformer_actor`, which checks its inputs first.

    Before any part runs: every key of ``in_keys`` but the mask present (else a
    :class:`~navformer_rl.modules.inputs.MissingKeyError` naming it and
    ``make_navformer_actor(in_keys=...)``), the frames ``[N, T, H, W, 3]`` (a flat ``[N * T]`` replay-buffer
    sample is named as such), and a batch without a mask whose timesteps show padding refused
    (``check_unmasked_padding``).
    """

    def __init__(self, *modules: TensorDictModuleBase, input_keys: dict[str, NestedKey]) -> None:
        super().__init__(*modules)
        self.input_keys = dict(input_keys)
        self.required = {
            key: INPUT_MEANINGS[name] for name, key in self.input_keys.items() if name not in OPTIONAL_INPUTS
        }
        self.rename_hint = (
            f"pass make_navformer_actor(model, in_keys=[...]) in the order {list(NAVFORMER_IN_KEYS)}"
        )

    @dispatch(auto_batch_size=False)
    def forward(self, tensordict: TensorDictBase, *args, **kwargs) -> TensorDictBase:
        require_keys(tensordict, self.required, "the NavFormer actor", self.rename_hint)
        keys = self.input_keys
        check_trajectory_steps(
            tensordict.get(keys["pixels"]), keys["pixels"], 3, "the NavFormer actor", "uint8 [N, T, H, W, 3]"
        )
        if tensordict.get(keys["mask"], None) is None:
            check_unmasked_padding(
                tensordict.get(keys["step"]), keys["mask"], keys["step"], "the NavFormer actor"
            )
        return super().forward(tensordict, *args, **kwargs)


def make_navformer_actor(
    model: NavFormerModel,
    in_keys: Sequence[NestedKey] = NAVFORMER_IN_KEYS,
    out_keys: Sequence[NestedKey] = NAVFORMER_OUT_KEYS,
    length_groups: int = 1,
) -> TensorDictSequential:
    """``model``'s parts as ``TensorDictSequential(dve_module, transformer_module, head_module)``.

    ``length_groups > 1`` runs the transformer and the head in that many groups of similar trajectory length
    (:class:`LengthGroups`; the encoders still see every valid frame in one pass): the same predictions
    without the padding's attention and token work (training lever, ``optim.length_groups``).

    Reads a trajectory batch and writes predicted actions, plus the parts' ``("embed", ..)`` and
    ``("hidden", ..)`` keys. Keys (defaults; pass ``in_keys`` in the same order to rename):

    ============== ========================================= ==========================================
    key            dtype / shape                             meaning
    ============== ========================================= ==========================================
    target_pixels  uint8 ``[N, 84, 84, 3]`` (or ``[N, T, ...]``) target image g (one per trajectory)
    pixels         uint8 ``[N, T, 84, 84, 3]``               observations o_t
    return_to_go   float32 ``[N, T, 1]``                     R-hat_t (eq. 3)
    action         float32 ``[N, T, 2]``                     actions a_t (teacher forcing)
    step           int64 ``[N, T]``                          absolute timestep, < ``max_timestep``
    mask           bool ``[N, T]``                           valid steps (padding on the right)
    action_pred    float32 ``[N, T, 2]`` (written)           a-hat_t in [-1, 1]; 0 on padded steps
    action_logits  float32 ``[N, T, 2, K]`` (written)        with ``BinnedActionHead`` only (``action_bins``)
    ============== ========================================= ==========================================

    The tensordict may have batch size ``[N]`` (per-step keys ``[N, T, ...]``, as the data package's
    ``TrajectoryBatcher`` yields) or ``[N, T]`` with ``target_pixels`` expanded over T. Swap a part by
    composing ``dve_module`` / ``transformer_module`` / ``head_module`` (or your own module on the same
    keys) in a ``TensorDictSequential``; the result works with ``ActionMSELoss`` (and, with a
    ``BinnedActionHead``, ``ActionBinLoss``).

    Inputs are checked before any part runs (:class:`NavFormerActor`): a missing key (``mask`` is optional),
    a flat ``[N * T]`` sample, or a padded batch without ``mask`` is one error naming the key to set.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
        >>> model = NavFormerModel(NavFormerConfig(d_embed=32, n_blocks=1, n_heads=2, d_head=16))
        >>> actor = make_navformer_actor(model)
        >>> n, t = 2, 5
        >>> batch = TensorDict(
        ...     {
        ...         "target_pixels": torch.zeros(n, 84, 84, 3, dtype=torch.uint8),
        ...         "pixels": torch.zeros(n, t, 84, 84, 3, dtype=torch.uint8),
        ...         "return_to_go": torch.ones(n, t, 1),
        ...         "action": torch.zeros(n, t, 2),
        ...         "step": torch.arange(t).expand(n, t),
        ...         "mask": torch.ones(n, t, dtype=torch.bool),
        ...     },
        ...     batch_size=[n],
        ... )
        >>> actor(batch)["action_pred"].shape
        torch.Size([2, 5, 2])
        >>> actor(batch.exclude("return_to_go"))
        Traceback (most recent call last):
        ...
        navformer_rl.modules.inputs.MissingKeyError: the NavFormer actor reads 'return_to_go'
            (float R-hat [N, T, 1]), ...
    """
    target_pixels, pixels, return_to_go, action, step, mask = _checked(
        in_keys, list(NAVFORMER_IN_KEYS), "in_keys"
    )
    (action_pred,) = _checked(out_keys, list(NAVFORMER_OUT_KEYS), "out_keys")
    transformer = model.transformer
    transformer_in = [
        (EMBED_KEY, "target"),
        *((EMBED_KEY, name) for name in transformer.observation_names),
        return_to_go,
        action,
        step,
        mask,
    ]
    per_step = [
        transformer_module(transformer, in_keys=transformer_in),
        head_module(
            model.head,
            in_keys=[*((HIDDEN_KEY, name) for name in model.head.reads), mask],
            out_keys=_head_out_keys(model.head, action_pred),
        ),
    ]
    if length_groups != 1:
        grouped = LengthGroups(
            TensorDictSequential(*per_step), length_groups, mask, per_trajectory_keys=[(EMBED_KEY, "target")]
        )
        per_step = [grouped]
    input_keys = dict(
        zip(NAVFORMER_IN_KEYS, (target_pixels, pixels, return_to_go, action, step, mask), strict=True)
    )
    return NavFormerActor(
        dve_module(model.dve, in_keys=[pixels, target_pixels, mask]), *per_step, input_keys=input_keys
    )
