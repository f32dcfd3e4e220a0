"""ActionBinLoss (the opt-in L_DT of ``model.action_bins``) under TorchRL's loss contract."""

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential

from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionBinLoss

from .contract import LossContract, padded_trajectories

BINS = 11


def bin_cross_entropy_by_hand(logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The two-hot target as hat functions on the bin centres (``1 - |x - c_k| / width``, clipped at 0: the
    two nearest centres, weighted by closeness), its cross-entropy summed over the action dims, mean over the
    valid steps."""
    centres = torch.linspace(-1.0, 1.0, logits.shape[-1])
    width = 2.0 / (logits.shape[-1] - 1)
    two_hot = (1.0 - (target.clamp(-1, 1)[..., None] - centres).abs() / width).clamp_min(0.0)
    cross_entropy = -(two_hot * logits.log_softmax(-1)).sum(-1).sum(-1)  # [N, T]
    return cross_entropy[mask].mean()


class TestActionBinLoss(LossContract):
    """TorchRL's loss contract (:class:`~tests.objectives.contract.LossContract`) for the binned L_DT."""

    out_keys = ("loss_dt",)
    default_keys = {"action_target": "action", "action_logits": "action_logits", "mask": "mask"}

    @staticmethod
    def make(seed: int = 0) -> tuple[NavFormerModel, ActionBinLoss]:
        torch.manual_seed(seed)
        model = NavFormerModel(NavFormerConfig(action_bins=BINS, dropout=0.0))
        return model, ActionBinLoss(make_navformer_actor(model))

    def batch(self) -> TensorDict:
        return padded_trajectories()

    def equation(self, model, loss, td) -> torch.Tensor:
        logits = make_navformer_actor(model)(td.copy())["action_logits"]
        return bin_cross_entropy_by_hand(logits, td["action"], td["mask"])

    def renamed(self, model, td):
        logits = make_navformer_actor(model)(td.copy())["action_logits"].detach()
        rename = TensorDictModule(lambda x: x, in_keys=["action_logits"], out_keys=["my_logits"])
        loss = ActionBinLoss(TensorDictSequential(make_navformer_actor(model), rename))
        loss.set_keys(action_target=("expert", "action"), action_logits="my_logits", mask="valid")
        target = torch.rand_like(td["action"]) * 2 - 1  # differs from the actor's input actions
        valid = torch.tensor([[True, False, True], [False, True, True]])
        td[("expert", "action")], td["valid"] = target, valid
        return loss, td, bin_cross_entropy_by_hand(logits, target, valid)
