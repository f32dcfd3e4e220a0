"""ActionMSELoss (L_DT, eq. 10): hand-computed values, masking, keys, composition with the actor, and
TorchRL's loss contract (``TestActionMSELoss``)."""

import warnings

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionMSELoss, masked_action_mse

from .contract import LossContract, padded_trajectories


class FixedPrediction(nn.Module):
    """Returns a fixed prediction tensor (plus 0 * a parameter so gradients exist)."""

    def __init__(self, prediction):
        super().__init__()
        self.prediction = prediction
        self.scale = nn.Parameter(torch.ones(()))

    def forward(self, action):
        return self.prediction * self.scale


def fixed_loss(prediction):
    actor = TensorDictModule(FixedPrediction(prediction), in_keys=["action"], out_keys=["action_pred"])
    return ActionMSELoss(actor)


def test_loss_on_hand_computed_values():
    target = torch.tensor([[[1.0, 0.0], [0.0, 0.0], [0.5, 0.5]]])  # [1, 3, 2]
    prediction = torch.tensor([[[0.0, 0.0], [0.0, 1.0], [9.0, 9.0]]])
    mask = torch.tensor([[True, True, False]])
    td = TensorDict({"action": target, "mask": mask}, batch_size=[1, 3])
    # valid steps: ||(1,0)-(0,0)||^2 = 1 and ||(0,0)-(0,1)||^2 = 1 -> mean 1; the padded step is ignored
    assert fixed_loss(prediction)(td)["loss_dt"].item() == pytest.approx(1.0)
    td_all = TensorDict({"action": target}, batch_size=[1, 3])  # no mask key: every step counts
    expected = (1 + 1 + (8.5**2) * 2) / 3
    loss = fixed_loss(prediction)
    with pytest.warns(UserWarning, match="no 'mask' and no 'step' to tell padding by"):  # once per loss
        assert loss(td_all)["loss_dt"].item() == pytest.approx(expected)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loss(td_all)


def test_set_keys_renames_inputs_and_rejects_unknown_names():
    target = torch.tensor([[[0.2, -0.2]]])
    prediction = torch.tensor([[[0.0, 0.0]]])
    loss = fixed_loss(prediction)
    loss.set_keys(action_target=("expert", "action"), mask="valid")
    td = TensorDict(
        {"action": target, ("expert", "action"): target, "valid": torch.ones(1, 1, dtype=torch.bool)}, [1, 1]
    )
    assert loss(td)["loss_dt"].item() == pytest.approx(0.08)
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(foo="bar")


def test_loss_with_the_navformer_actor_ignores_padding_and_backpropagates(td_factory):
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig(dropout=0.0))
    loss_module = ActionMSELoss(make_navformer_actor(model))
    td = td_factory(2, 4)
    td["mask"][1, 2:] = False
    loss = loss_module(td)["loss_dt"]
    junk = td.clone()
    junk["action"][1, 2:] = 5.0
    junk["pixels"][1, 2:] = 0
    torch.testing.assert_close(loss_module(junk)["loss_dt"], loss, rtol=0, atol=1e-7)
    loss.backward()
    assert model.head.weight.grad is not None and model.static_encoder.linear.weight.grad.abs().sum() > 0
    assert "action_pred" not in td.keys()  # the loss works on a shallow copy
    assert set(loss_module.in_keys) >= {"action", "mask", "pixels", "target_pixels"}


class TestActionMSELoss(LossContract):
    """TorchRL's loss contract (:class:`~tests.objectives.contract.LossContract`) for L_DT (eq. 10)."""

    out_keys = ("loss_dt",)
    default_keys = {"action_target": "action", "action_pred": "action_pred", "mask": "mask"}

    @staticmethod
    def make(seed: int = 0, **config) -> tuple[NavFormerModel, ActionMSELoss]:
        torch.manual_seed(seed)
        model = NavFormerModel(NavFormerConfig(dropout=0.0, **config))  # deterministic forward passes
        return model, ActionMSELoss(make_navformer_actor(model))

    def batch(self) -> TensorDict:
        return padded_trajectories()

    def equation(self, model, loss, td) -> torch.Tensor:
        prediction = make_navformer_actor(model)(td.copy())["action_pred"]
        squared = (prediction - td["action"]).pow(2).sum(-1)  # ||a - a-hat||^2 over the action dims
        return squared[td["mask"]].mean()  # averaged over the valid steps

    def renamed(self, model, td):
        prediction = make_navformer_actor(model)(td.copy())["action_pred"].detach()
        loss = ActionMSELoss(make_navformer_actor(model, out_keys=("my_pred",)))
        loss.set_keys(action_target=("expert", "action"), action_pred="my_pred", mask="valid")
        target = torch.zeros_like(td["action"])  # differs from the actor's input actions
        valid = torch.tensor([[True, False, True], [False, True, True]])
        td[("expert", "action")], td["valid"] = target, valid
        return loss, td, masked_action_mse(prediction, target, valid)

    @pytest.mark.parametrize("detach_encoders", [False, True])
    def test_gradients_reach_the_encoders_only_when_they_train_with_l_dt(self, detach_encoders):
        model, loss = self.make(detach_encoders=detach_encoders)
        loss(self.batch())["loss_dt"].backward()
        assert model.head.weight.grad is not None and model.head.weight.grad.abs().sum() > 0
        for encoder in (model.static_encoder, model.general_encoder):
            grads = [p.grad for p in encoder.parameters()]
            if detach_encoders:  # frozen-encoder mode: L_DT trains the transformer and head only
                assert all(g is None for g in grads)
            else:
                assert any(g is not None and g.abs().sum() > 0 for g in grads)
