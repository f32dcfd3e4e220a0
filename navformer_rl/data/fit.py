"""Whether a model can read a dataset: image size, action width and trajectory length against its config."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def check_model_reads(
    model: Any, datasets: Mapping[str, Any], names: Mapping[str, str], tunable: bool
) -> None:
    """Raise ``ValueError`` when a model of ``model`` (a ``NavFormerConfig``) cannot read ``datasets``.

    Checked: every dataset's images (``pixels``, ``pixels_static``, ``pixels_dynamic``) are ``image_size``
    square RGB; trajectory actions are ``action_dim`` wide; the longest trajectory's last step fits the
    timestep table (``< max_timestep``). Without it a mismatch would surface as a shape error deep in the
    first forward pass, or - for the timestep - only once a long trajectory is drawn, possibly hours in.

    Args:
        model: the ``NavFormerConfig``.
        datasets: ``{kind: NavDataset}``.
        names: ``{kind: what the message calls the dataset}`` (e.g. its config key).
        tunable: the model is still to be built, so the message may advise raising ``model.max_timestep``.
    """
    image_shape = (model.image_size, model.image_size, 3)
    for kind, dataset in datasets.items():
        name = names[kind]
        for key in ("pixels", "pixels_static", "pixels_dynamic"):
            if key in dataset.rows.keys() and tuple(dataset.rows[key].shape[1:]) != image_shape:
                raise ValueError(
                    f"{name}: images are {tuple(dataset.rows[key].shape[1:])}, but model.image_size="
                    f"{model.image_size} expects {image_shape}"
                )
        if dataset.episodes is None:
            continue
        if dataset.rows["action"].shape[-1] != model.action_dim:
            raise ValueError(
                f"{name}: actions have {dataset.rows['action'].shape[-1]} dimensions, but "
                f"model.action_dim={model.action_dim}"
            )
        longest = int(dataset.episodes.length.max())
        if longest > model.max_timestep:
            advice = f"; raise model.max_timestep to at least {longest}" if tunable else ""
            raise ValueError(
                f"{name}: its longest trajectory has {longest} steps, but model.max_timestep="
                f"{model.max_timestep} embeds timesteps 0..{model.max_timestep - 1}{advice}"
            )
