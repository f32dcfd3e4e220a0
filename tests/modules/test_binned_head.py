"""The opt-in binned action head (``model.action_bins``) and its loss: known answers, masks, gradients and the
training actor with length groups."""

import math

import pytest
import torch
from tensordict import TensorDict

from navformer_rl.modules import BinnedActionHead, NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionBinLoss, ActionMSELoss, masked_bin_cross_entropy, two_hot

KEYS = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")


def binned_model(seed=0, **changes):
    torch.manual_seed(seed)
    return NavFormerModel(NavFormerConfig(action_bins=11, dropout=0.0, **changes))


@pytest.mark.parametrize("bins", [1, -3, 2.5])
def test_the_config_refuses_a_bin_count_that_is_not_zero_or_at_least_two(bins):
    with pytest.raises(ValueError, match=f"action_bins={bins!r}: expected 0"):
        NavFormerConfig(action_bins=bins)


def test_two_hot_keeps_the_action_as_its_mean_and_sums_to_one():
    actions = torch.tensor([-1.0, -0.93, -0.2, 0.0, 0.35, 0.999, 1.0, 1.4])  # 1.4: clamped to 1
    probabilities = two_hot(actions, 11)
    centres = torch.linspace(-1, 1, 11)
    torch.testing.assert_close(probabilities.sum(-1), torch.ones(8))
    torch.testing.assert_close((probabilities * centres).sum(-1), actions.clamp(-1, 1))
    assert ((probabilities > 0).sum(-1) <= 2).all()
    assert probabilities[0, 0] == 1 and probabilities[6, -1] == 1 and probabilities[3, 5] == 1


def test_decoding_commits_to_the_likelier_of_two_turns_where_a_mean_would_not_turn():
    head = BinnedActionHead(("observation",), 4, 1, 11)
    probabilities = torch.zeros(1, 1, 1, 11)
    probabilities[..., 1] = 0.45  # a left turn at -0.8 ...
    probabilities[..., 9] = 0.55  # ... or a slightly likelier right turn at +0.8
    action = head.decode(probabilities.clamp_min(1e-9).log())
    mean = (probabilities * head.centres).sum(-1)
    assert action.item() == pytest.approx(0.8, abs=1e-5)
    assert abs(mean.item()) < 0.1  # what a squared-error head converges to in such a state


def test_decoding_recovers_an_action_between_two_bins_and_at_the_edges():
    head = BinnedActionHead(("observation",), 4, 1, 21)
    for value in (-1.0, -0.437, 0.0, 0.26, 0.95, 1.0):
        logits = two_hot(torch.tensor([value]), 21).clamp_min(1e-12).log()
        assert head.decode(logits).item() == pytest.approx(value, abs=1e-5)


def test_the_head_writes_actions_and_logits_and_zeros_on_padded_steps(batch_factory):
    model = binned_model().eval()
    batch = batch_factory(2, 5)
    batch["mask"][1, 3:] = False
    out = make_navformer_actor(model)(TensorDict(batch, [2]))
    assert out["action_pred"].shape == (2, 5, 2) and out["action_logits"].shape == (2, 5, 2, 11)
    assert out["action_pred"].abs().max() <= 1
    assert (out["action_pred"][1, 3:] == 0).all() and (out["action_logits"][1, 3:] == 0).all()
    with torch.no_grad():
        direct = model(*(batch[k] for k in KEYS))
    torch.testing.assert_close(direct, out["action_pred"])


def test_the_loss_is_the_targets_entropy_when_the_logits_are_the_target():
    target = torch.tensor([[[0.3, -0.55], [1.0, 0.0]]])  # [1, 2, 2]
    probabilities = two_hot(target, 11)
    logits = probabilities.clamp_min(1e-30).log()
    entropy = -(probabilities * probabilities.clamp_min(1e-30).log()).sum(-1).sum(-1)  # per step
    loss = masked_bin_cross_entropy(logits, target, torch.tensor([[True, True]]))
    assert loss.item() == pytest.approx(entropy.mean().item(), abs=1e-5)
    # a padded step does not count, whatever its logits
    masked = masked_bin_cross_entropy(
        torch.stack([logits[:, 0], torch.zeros_like(logits[:, 1])], 1), target, torch.tensor([[True, False]])
    )
    assert masked.item() == pytest.approx(entropy[0, 0].item(), abs=1e-5)
    # uniform logits: ln K per action dimension
    uniform = masked_bin_cross_entropy(torch.zeros(1, 2, 2, 11), target, None)
    assert uniform.item() == pytest.approx(2 * math.log(11), rel=1e-6)


def test_the_loss_trains_the_head_and_the_transformer_through_length_groups(batch_factory):
    batch = TensorDict(batch_factory(4, 6, seed=2), [4])
    batch["mask"][1, 4:] = False
    batch["mask"][2, 2:] = False
    losses, grads = {}, {}
    for groups in (1, 3):
        model = binned_model().train()
        loss = ActionBinLoss(make_navformer_actor(model, length_groups=groups))(batch.clone())
        assert list(loss.keys()) == ["loss_dt"]
        loss["loss_dt"].backward()
        losses[groups] = loss["loss_dt"].item()
        grads[groups] = {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}
    assert losses[3] == pytest.approx(losses[1], rel=1e-5)
    for name in ("head.linear.weight", "transformer.gpt.blocks.0.attn.qkv.weight"):
        assert grads[1][name].abs().sum() > 0
        torch.testing.assert_close(grads[3][name], grads[1][name], rtol=1e-4, atol=1e-6)


def test_the_loss_names_a_missing_logits_key_and_the_mse_loss_still_scores_the_predictions(batch_factory):
    batch = TensorDict(batch_factory(2, 3), [2])
    regression = NavFormerModel(NavFormerConfig(dropout=0.0))
    with pytest.raises(KeyError, match="action_logits"):
        ActionBinLoss(make_navformer_actor(regression))(batch)
    # validation's eq. 10 error works on a binned model's decoded actions
    assert ActionMSELoss(make_navformer_actor(binned_model().eval()))(batch)["loss_dt"].item() > 0
