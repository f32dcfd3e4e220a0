"""Numbers and names fixed by the paper's protocol (§III, §VII.A, Table IV), shared by every component."""

CONTROL_DT = 0.2
"""Seconds per env step (paper §VII.A: 'Each timestep is 0.2 s')."""

MAX_EPISODE_STEPS = 500
"""A trial ends after 500 steps (paper §VII.A)."""

SUCCESS_RADIUS = 1.5
"""A robot has found its target within 1.5 m of it (paper §VII.A)."""

IMAGE_SIZE = 84
"""Camera frames and target images are 84 x 84 x 3 uint8, stored HWC (paper §IV.B)."""

EVAL_SIZES = (7.5, 12.5, 17.5)
EVAL_ROBOT_COUNTS = (2, 4, 6)
MIN_WORLD_SIZE = 5.0
MAX_WORLD_SIZE = 17.5

TARGET_SHAPES = ("sphere", "box")
TARGET_COLORS = ("green", "red", "white", "yellow", "blue")

ABLATIONS: dict[str, str] = {
    "none": "NavFormer as in the paper",
    "no_ssl": "w/o SSL: trained with L_DT only (no BYOL, no D_ssl)",
    "no_thsc": "w/o THSC: the action head reads h^ca_{o,t} only",
    "no_de": "w/o tau^e: L_DT on D_ca trajectories only",
    "no_dca": "w/o tau^ca: L_DT on D_e trajectories only",
    "no_fs": "w/o f_s: no static encoder (and no static BYOL)",
    "no_fg": "w/o f_g: no general encoder (target image through f_s)",
    "resnet18": "w ResNet18: a single, randomly initialised ResNet18 replaces the DVE",
    "dt": "DT baseline: single encoder, no THSC, trained with eq. 10 only",
}
"""Every value of ``TrainConfig.ablation``: the rows of paper Table IV plus the DT baseline (Table I)."""
