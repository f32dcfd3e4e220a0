"""NavFormer losses: ``ActionMSELoss`` (L_DT, eq. 10, key ``loss_dt``) and ``BYOLLoss`` (L_BYOL, eqs. 6-8, key
``loss_byol``); L = L_BYOL + L_DT (eq. 11) is the sum of the ``loss*`` entries of both outputs.
``ActionBinLoss``: the opt-in L_DT (key ``loss_dt``) of a model with ``action_bins``; both on
``TeacherForcedActionLoss``, the base for another teacher-forced action loss."""

from navformer_rl.objectives.bin_loss import ActionBinLoss, masked_bin_cross_entropy, two_hot
from navformer_rl.objectives.byol import BYOLLoss, BYOLTauSchedule, byol_tau, joint_parameters, normalized_mse
from navformer_rl.objectives.dt_loss import ActionMSELoss, TeacherForcedActionLoss, masked_action_mse

__all__ = [
    "ActionBinLoss",
    "ActionMSELoss",
    "BYOLLoss",
    "BYOLTauSchedule",
    "TeacherForcedActionLoss",
    "byol_tau",
    "joint_parameters",
    "masked_action_mse",
    "masked_bin_cross_entropy",
    "normalized_mse",
    "two_hot",
]
