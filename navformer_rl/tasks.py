"""The project's vocabulary in one place: the paper's datasets and sub-tasks with their config keys, and the
ablations of Table IV (plus the DT baseline of Table I) with what each one trains.

Every other module takes these names from here: the dataset kinds of ``navformer collect`` and of the stored
``metadata.json`` (``"e"``, ``"ca"``, ``"ssl"``), the ``task`` value stored per row and the task names of the
training logs (``loss_dt_exploration``), the ``data.*`` / ``validation.*`` keys of ``navformer train``, the
``ablation=`` values and the model each builds, and the Table IV row an evaluation label is compared with.
Importing this module imports nothing heavy (no torch), so command-line help can use it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Dataset:
    """One of the three datasets of paper §V.

    Attributes:
        kind: the name in commands and ``metadata.json`` (``navformer collect e|ca|ssl``).
        paper_name: the paper's symbol.
        task: the sub-task a trajectory dataset teaches (§VI), the suffix of its training log columns
            (``loss_dt_<task>``); None for D_ssl.
        task_id: the value of the stored ``task`` key of its rows; None for D_ssl.
        path_key: the folder key, ``data.<path_key>`` (and ``validation.<path_key>`` for held-out sets).
        batch_key: ``data.<batch_key>``, trajectories (pairs) per batch.
        subset_key: ``data.<subset_key>``, train on the folder's first N items only.
    """

    kind: str
    paper_name: str
    task: str | None
    task_id: int | None
    path_key: str
    batch_key: str
    subset_key: str


DATASETS: dict[str, Dataset] = {
    "e": Dataset(
        "e",
        "D_e",
        "exploration",
        0,
        "exploration_path",
        "exploration_batch_trajs",
        "exploration_trajectories",
    ),
    "ca": Dataset(
        "ca",
        "D_ca",
        "collision_avoidance",
        1,
        "collision_path",
        "collision_batch_trajs",
        "collision_trajectories",
    ),
    "ssl": Dataset("ssl", "D_ssl", None, None, "ssl_path", "ssl_batch_pairs", "ssl_pairs"),
}
"""The datasets by kind."""

TRAJECTORY_KINDS: tuple[str, ...] = tuple(kind for kind, d in DATASETS.items() if d.task is not None)
"""The kinds whose items are trajectories (D_e, D_ca): the cross-task training alternates between them."""


@dataclass(frozen=True)
class Ablation:
    """One value of ``ablation=``: what the run trains on and which model it builds.

    Attributes:
        name: the ``ablation=`` value (and the suffix of an evaluation label, ``navformer-<name>``).
        description: one line for help texts.
        paper_row: the row of the paper's Table IV it reproduces (None: NavFormer itself and DT).
        datasets: the dataset kinds its losses read.
        static_encoder / general_encoder: which encoders of the dual visual encoder it keeps.
        encoder: ``"cnn"`` (the paper's CNN) or ``"resnet18"``.
        thsc: whether the action head reads ``[h_g; h_o^ca]`` (THSC) or ``h_o`` alone.
    """

    name: str
    description: str
    paper_row: str | None
    datasets: tuple[str, ...] = ("e", "ca", "ssl")
    static_encoder: bool = True
    general_encoder: bool = True
    encoder: str = "cnn"
    thsc: bool = True

    @property
    def uses_ssl(self) -> bool:
        return "ssl" in self.datasets

    @property
    def model_switches(self) -> dict[str, object]:
        """``NavFormerConfig`` fields that differ from the paper's model."""
        paper = Ablation("none", "", None)
        fields = {
            "use_static_encoder": (self.static_encoder, paper.static_encoder),
            "use_general_encoder": (self.general_encoder, paper.general_encoder),
            "encoder": (self.encoder, paper.encoder),
            "thsc": (self.thsc, paper.thsc),
        }
        return {key: value for key, (value, default) in fields.items() if value != default}


ABLATIONS: dict[str, Ablation] = {
    a.name: a
    for a in (
        Ablation("none", "NavFormer as in the paper", None),
        Ablation(
            "no_ssl", "w/o SSL: trained with L_DT only (no BYOL, no D_ssl)", "NavFormer w/o SSL", ("e", "ca")
        ),
        Ablation(
            "no_thsc", "w/o THSC: the action head reads h^ca_{o,t} only", "NavFormer w/o THSC", thsc=False
        ),
        Ablation("no_de", "w/o tau^e: L_DT on D_ca trajectories only", "NavFormer w/o tau^e", ("ca", "ssl")),
        Ablation("no_dca", "w/o tau^ca: L_DT on D_e trajectories only", "NavFormer w/o tau^ca", ("e", "ssl")),
        Ablation(
            "no_fs",
            "w/o f_s: no static encoder (and no static BYOL)",
            "NavFormer w/o f_s",
            static_encoder=False,
        ),
        Ablation(
            "no_fg",
            "w/o f_g: no general encoder (target image through f_s)",
            "NavFormer w/o f_g",
            general_encoder=False,
        ),
        Ablation(
            "resnet18",
            "w ResNet18: a single, randomly initialised ResNet18 replaces the DVE",
            "NavFormer w ResNet18",
            static_encoder=False,
            encoder="resnet18",
        ),
        Ablation(
            "dt",
            "DT baseline: single encoder, no THSC, trained with eq. 10 only",
            None,
            ("e", "ca"),
            static_encoder=False,
            thsc=False,
        ),
    )
}
"""Every value of ``ablation=``: the rows of paper Table IV plus the DT baseline (Table I)."""


def label_ablation(label: str) -> str | None:
    """The Table IV ablation an evaluation label names, or None.

    A label names one when it is ``navformer`` followed by ``-`` or ``_`` and then, as one of its
    ``-``-separated words, the ablation's exact name: ``navformer-no_thsc``, ``navformer_resnet18`` and
    ``navformer-no_fs-seed1`` name ``no_thsc``, ``resnet18`` and ``no_fs``; ``navformer``,
    ``navformer-seed1``, ``navformer-byol_w0.1``, ``dt-no_thsc`` and ``vrw`` name none. The baseline ``dt``
    and ``none`` are not Table IV rows.
    """
    match = re.fullmatch(r"navformer[-_](.+)", label.lower())
    if match is None:
        return None
    words = match.group(1).split("-")
    named = [w for w in words if w in ABLATIONS and ABLATIONS[w].paper_row is not None]
    return named[0] if named else None
