"""``ActionMSELoss``: L_DT, the masked action MSE that trains NavFormer (paper eq. 10), on the shared
``TeacherForcedActionLoss`` base."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictParams, dispatch
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from navformer_rl.modules.inputs import MissingKeyError, check_unmasked_padding, require_keys


class TeacherForcedActionLoss(LossModule):
    """Base of the L_DT losses: run the actor on (a shallow copy of) a trajectory batch, read its prediction
    (the key named by ``prediction_key``, a field of ``tensor_keys``) and the expert actions, return
    ``loss_dt`` from :meth:`action_loss`. The mask checks and the error messages are shared; a subclass
    names its keys (``_AcceptedKeys``), the prediction's expected shape and the loss."""

    prediction_key: str = "action_pred"
    """The ``tensor_keys`` field naming the actor output the loss reads."""
    actor_network: TensorDictModule
    actor_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams

    def __init__(self, actor_network: TensorDictModule) -> None:
        super().__init__()
        self.convert_to_functional(actor_network, "actor_network", create_target_params=False)
        self._out_keys = ["loss_dt"]
        self._warned_unmasked = False

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self) -> list[NestedKey]:
        keys = set(self.actor_network.in_keys) | {self.tensor_keys.action_target, self.tensor_keys.mask}
        return sorted(keys, key=str)

    @property
    def out_keys(self) -> list[str]:
        return self._out_keys

    @out_keys.setter
    def out_keys(self, values: list[str]) -> None:
        self._out_keys = list(values)

    def check_inputs(self, tensordict: TensorDictBase) -> None:
        """Refuse a batch the loss cannot score, in one line naming the key to set
        (:class:`~navformer_rl.modules.inputs.MissingKeyError` for a missing one): the expert actions
        (``action_target``), every key the actor reads but the mask, and - without a mask - TorchRL's
        ``("collector", "mask")`` left unused or timesteps (``step``) that show padding. Without a mask and
        without ``step`` to tell, it warns once that every step counts as valid."""
        keys, name = self.tensor_keys, type(self).__name__
        present = set(tensordict.keys(include_nested=True))
        required = {keys.action_target: "the expert actions [N, T, A], the action_target key"}
        required |= {
            key: "read by the actor"
            for key in self.actor_network.in_keys
            if key not in (keys.mask, keys.action_target)
        }
        require_keys(
            tensordict,
            required,
            name,
            "rename it with loss.set_keys(action_target=...) or the actor's in_keys "
            "(make_navformer_actor(model, in_keys=[...]))",
        )
        if keys.mask in present:
            return
        if ("collector", "mask") in present:
            raise MissingKeyError(
                f"{name}: the batch has ('collector', 'mask') but no {keys.mask!r}; padded steps would "
                "count as valid. Use loss.set_keys(mask=('collector', 'mask')) or copy the mask to that key"
            )
        if "step" in present:
            check_unmasked_padding(tensordict.get("step"), keys.mask, "step", name)
        elif not self._warned_unmasked:
            self._warned_unmasked = True
            warnings.warn(
                f"{name}: the batch has no {keys.mask!r} and no 'step' to tell padding by; every step counts "
                f"as valid. Set {keys.mask!r} (bool [N, T]) if the trajectories are padded",
                stacklevel=6,  # the caller of loss(batch): past forward, dispatch and nn.Module's call
            )

    def check_prediction(self, prediction: torch.Tensor, target: torch.Tensor) -> None:
        """Raise ``ValueError`` when the prediction's shape does not fit the targets ``[N, T, A]``."""
        if prediction.shape != target.shape:
            raise ValueError(
                f"{getattr(self.tensor_keys, self.prediction_key)}: shape {tuple(prediction.shape)} does not "
                f"match {self.tensor_keys.action_target}: {tuple(target.shape)}"
            )

    def action_loss(
        self, prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None
    ) -> torch.Tensor:
        """The scalar loss over the valid steps."""
        raise NotImplementedError

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Run the actor on (a shallow copy of) ``tensordict`` and return ``loss_dt``."""
        tensordict = tensordict.copy()
        keys, name = self.tensor_keys, type(self).__name__
        prediction_key = getattr(keys, self.prediction_key)
        self.check_inputs(tensordict)
        target = tensordict.get(keys.action_target).detach()
        with self.actor_network_params.to_module(self.actor_network):
            prediction = self.actor_network(tensordict).get(prediction_key, None)
        if prediction is None:
            raise KeyError(
                f"{name}: the actor did not write {prediction_key!r} ({self.prediction_key} key); its "
                f"out_keys are {self.actor_network.out_keys}"
            )
        self.check_prediction(prediction, target)
        loss = self.action_loss(prediction, target, tensordict.get(keys.mask, None))
        return TensorDict({"loss_dt": loss}, batch_size=[])


class ActionMSELoss(TeacherForcedActionLoss):
    """L_DT (eq. 10): masked action MSE over the valid steps of a trajectory batch.

    ``loss_dt = sum_{n,t valid} || a_{n,t} - a-hat_{n,t} ||^2 / #valid`` - the squared error is summed over
    the action dimensions (eq. 10's squared norm) and averaged over every valid step of the batch.
    (TorchRL's ``DTLoss`` averages over action dimensions too, i.e. half of this for 2-D actions, and
    masks only through ``("collector", "mask")``; this module reads the ``mask`` key directly.)

    Keys (``set_keys``): ``action_target`` (default ``"action"``, float ``[N, T, A]``), ``action_pred``
    (default ``"action_pred"``, written by the actor), ``mask`` (default ``"mask"``, bool ``[N, T]``, the only
    optional input: a tensordict without it counts every step as valid; one holding TorchRL's
    ``("collector", "mask")`` instead, or whose ``step`` shows padding, is refused rather than scored).
    A missing key (the targets, or any key the actor reads) is a ``MissingKeyError`` (a ``KeyError`` and a
    ``ValueError``) naming it, before the actor runs (:meth:`check_inputs`). Output (``out_keys``):
    ``loss_dt``, the scalar L_DT, its only entry (``select_out_keys`` / ``reset_out_keys`` work as on
    TorchRL's losses). The input tensordict is left unchanged: the actor runs on a shallow copy.
    ``reset_parameters_recursive()`` re-draws the actor's parameters (each layer's ``reset_parameters``).

    Args:
        actor_network: a ``TensorDictModule`` writing ``action_pred`` (``make_navformer_actor(model)``).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
        >>> from navformer_rl.objectives import ActionMSELoss
        >>> model = NavFormerModel(NavFormerConfig(d_embed=32, n_blocks=1, n_heads=2, d_head=16))
        >>> loss = ActionMSELoss(make_navformer_actor(model))
        >>> n, t = 2, 6  # two trajectories, the second one 4 steps long (right padding, masked)
        >>> batch = TensorDict(
        ...     {
        ...         "target_pixels": torch.zeros(n, 84, 84, 3, dtype=torch.uint8),
        ...         "pixels": torch.zeros(n, t, 84, 84, 3, dtype=torch.uint8),
        ...         "return_to_go": torch.ones(n, t, 1),
        ...         "action": torch.rand(n, t, 2) * 2 - 1,
        ...         "step": torch.arange(t).expand(n, t),
        ...         "mask": torch.arange(t) < torch.tensor([[6], [4]]),
        ...     },
        ...     batch_size=[n],
        ... )
        >>> out = loss(batch)
        >>> out["loss_dt"].shape, out["loss_dt"].requires_grad
        (torch.Size([]), True)
        >>> out["loss_dt"].backward()  # into the model's parameters (train with AdamW, as §VI)
        >>> loss.set_keys(action_target="expert_action")  # a batch naming its targets otherwise
        >>> loss(batch)
        Traceback (most recent call last):
        ...
        navformer_rl.modules.inputs.MissingKeyError: ActionMSELoss reads 'expert_action' (the expert actions
            [N, T, A], the action_target key), ...
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            action_target: expert actions a_t. Defaults to ``"action"``.
            action_pred: predicted actions a-hat_t written by the actor. Defaults to ``"action_pred"``.
            mask: valid steps (bool). Defaults to ``"mask"``.
        """

        action_target: NestedKey = "action"
        action_pred: NestedKey = "action_pred"
        mask: NestedKey = "mask"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    prediction_key = "action_pred"

    def action_loss(
        self, prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None
    ) -> torch.Tensor:
        return masked_action_mse(prediction, target, mask)


def masked_action_mse(
    prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None
) -> torch.Tensor:
    """Eq. 10 on tensors: ``[N, T, A] x [N, T, A] x bool [N, T] -> scalar`` (see ``ActionMSELoss``)."""
    squared_error = (prediction.float() - target.float()).pow(2).sum(-1)
    if mask is None:
        return squared_error.mean()
    return torch.where(mask, squared_error, 0.0).sum() / mask.sum().clamp_min(1)
