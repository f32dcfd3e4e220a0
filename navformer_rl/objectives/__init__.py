"""NavFormer losses: ``NavFormerLoss`` (eq. 10) and ``BYOLLoss`` (eqs. 6-8); L = L_BYOL + L_DT (eq. 11)."""

from navformer_rl.objectives.byol import BYOLLoss, BYOLTauSchedule, byol_tau, joint_parameters, normalized_mse
from navformer_rl.objectives.navformer import NavFormerLoss, masked_action_mse

__all__ = [
    "BYOLLoss",
    "BYOLTauSchedule",
    "NavFormerLoss",
    "byol_tau",
    "joint_parameters",
    "masked_action_mse",
    "normalized_mse",
]
