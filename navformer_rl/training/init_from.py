"""Fine-tuning: ``init_from=CHECKPOINT`` starts a run from trained weights with fresh optimisers and
schedules.

The source is any checkpoint form :func:`~navformer_rl.training.checkpoint.resolve_checkpoint` takes: a run
directory (its latest checkpoint), a checkpoint folder or a file in it, or ``pretrained:NAME`` (shipped
weights, sha256-checked). Only its run part is read (``config.json`` + ``model.safetensors``): the
``NavFormerModel`` weights. Everything else starts as in a new run - iteration 0, fresh AdamW / Adam states,
BYOL's tau schedule from ``ssl.tau_base``, the samplers from ``seed`` - and the BYOL projector / predictor
heads are new (they are not part of the run part), with the EMA target a copy of the loaded encoders and the
new heads.

The source's model must be the configured one: every ``NavFormerConfig`` field but the training levers of
:data:`MAY_DIFFER` (dropout and the speed settings) must be equal, else the run is refused before anything
is built. The run files record the source's identity (:class:`InitSource`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.config import TrainConfig, model_config
from navformer_rl.training.pretrained_registry import file_sha256

if TYPE_CHECKING:
    from navformer_rl.training.trainer import Trainer

MAY_DIFFER = frozenset(
    {
        "dropout",
        "action_dropout",
        "detach_encoders",
        "encoder_micro_batch",
        "autocast_dtype",
        "channels_last",
        "space_to_depth",
    }
)
"""``NavFormerConfig`` fields a fine-tuning run may set otherwise than its source: regularisation and the
training levers (``docs/model.md``); the weights fit the model either way."""


@dataclass(frozen=True)
class InitSource:
    """The checkpoint a run starts from.

    Attributes:
        checkpoint: ``init_from`` as configured (a path or ``pretrained:NAME``).
        folder: the checkpoint folder it resolves to.
        iteration: the source's completed training iterations.
        weights_sha256: sha256 of its ``model.safetensors`` (which weights, whatever the path).
    """

    checkpoint: str
    folder: str
    iteration: int
    weights_sha256: str

    def record(self) -> dict[str, Any]:
        """The JSON record written into the run files (``run.init_from``)."""
        return dataclasses.asdict(self)


def resolve_init_source(cfg: TrainConfig) -> InitSource:
    """The checkpoint ``cfg.init_from`` names, after checking that its model is the configured one.

    Raises:
        FileNotFoundError / ValueError: no checkpoint there (the message lists the accepted forms), an unknown
            or corrupt ``pretrained:NAME``, a foreign file; or a model that differs from the configured one in
            a field outside :data:`MAY_DIFFER` (the message names each field, both values, and the keys to
            set).
    """
    from navformer_rl.modules import NavFormerConfig

    designation = str(cfg.init_from)
    try:
        folder = ckpt.resolve_checkpoint(designation)
        header = ckpt.read_checkpoint_config(folder)
        source = ckpt.read_model_config(folder)
    except (FileNotFoundError, ValueError) as error:
        raise type(error)(f"init_from={designation}: {error}") from None
    configured = model_config(cfg)
    differ = [
        f"{f.name} (checkpoint {getattr(source, f.name)!r}, configured {getattr(configured, f.name)!r})"
        for f in dataclasses.fields(NavFormerConfig)
        if f.name not in MAY_DIFFER and getattr(source, f.name) != getattr(configured, f.name)
    ]
    if differ:
        raise ValueError(
            f"init_from={designation}: the checkpoint's model differs from the configured one in "
            f"{', '.join(differ)}; set ablation= / model.<key>= to the checkpoint's values"
        )
    return InitSource(
        checkpoint=designation,
        folder=str(folder.resolve()),
        iteration=int(header["iteration"]),
        weights_sha256=file_sha256(folder / ckpt.WEIGHTS_FILENAME),
    )


def load_initial_weights(trainer: Trainer, source: InitSource) -> None:
    """Load ``source``'s model weights into a freshly built ``trainer`` (its optimisers hold no state yet) and
    restart BYOL's EMA target as a copy of the online networks (the loaded encoders, the new heads)."""
    _, weights = ckpt.load_model_state(source.folder)
    ckpt.load_model_weights(trainer.model, weights, source.folder)
    if trainer.byol_loss is not None:
        trainer.byol_loss.target_online_network_params.data.update_(
            trainer.byol_loss.online_network_params.data
        )
    trainer.run_info["init_from"] = source.record()
