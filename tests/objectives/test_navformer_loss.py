"""NavFormerLoss (eq. 10): hand-computed values, masking, keys, composition with the actor."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import NavFormerLoss


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
    return NavFormerLoss(actor)


def test_loss_on_hand_computed_values():
    target = torch.tensor([[[1.0, 0.0], [0.0, 0.0], [0.5, 0.5]]])  # [1, 3, 2]
    prediction = torch.tensor([[[0.0, 0.0], [0.0, 1.0], [9.0, 9.0]]])
    mask = torch.tensor([[True, True, False]])
    td = TensorDict({"action": target, "mask": mask}, batch_size=[1, 3])
    # valid steps: ||(1,0)-(0,0)||^2 = 1 and ||(0,0)-(0,1)||^2 = 1 -> mean 1; the padded step is ignored
    assert fixed_loss(prediction)(td)["loss_dt"].item() == pytest.approx(1.0)
    td_all = TensorDict({"action": target}, batch_size=[1, 3])  # no mask key: every step counts
    expected = (1 + 1 + (8.5**2) * 2) / 3
    assert fixed_loss(prediction)(td_all)["loss_dt"].item() == pytest.approx(expected)


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
    loss_module = NavFormerLoss(make_navformer_actor(model))
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
