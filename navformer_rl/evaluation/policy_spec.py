"""What the harness evaluates: a method (or your own policy factory) and its checkpoint, and their checks.

:class:`PolicySpec` is the picklable policy recipe every evaluation worker builds its policy from;
``PolicySpec.validate`` checks it once, before any episode runs, and describes it for ``run.json``
(``model_config``, ``checkpoint_sha256``, training ``ablation``). :func:`checkpoint_ablation` reads the
training ablation a checkpoint was trained with (its ``config.json``, else the run directory's
``train_config.json``); :func:`label_ablation_problem` refuses labels that misname the evaluated model
(a training ablation it was not trained with, or another method's name).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from navformer_rl.evaluation.paper_results import ABLATION_TO_TABLE4
from navformer_rl.tasks import label_ablation
from navformer_rl.utils.devices import check_device, resolve_device

METHODS: tuple[str, ...] = ("navformer", "dt", "vrw", "fca", "dsac", "matdn", "frontier")
"""Methods the harness can run (``frontier``: the D_e exploration expert, not a paper baseline).
``navformer`` / ``dt`` (training checkpoints) and ``dsac`` / ``matdn`` (PPO checkpoints, ``navformer
train-ppo``) need a checkpoint."""
CHECKPOINT_METHODS = ("navformer", "dt")
"""The methods whose checkpoint holds a ``NavFormerModel`` (run by ``NavFormerPolicy``)."""
ONLINE_METHODS = ("dsac", "matdn")
"""The baselines trained online with PPO (:mod:`navformer_rl.baselines.online`); mirrors its
``ONLINE_METHODS`` (not imported here: this module stays free of torch)."""
TRAIN_CONFIG_FILENAME = "train_config.json"
"""The resolved training configuration a training run writes into its run directory."""


@dataclass(frozen=True)
class PolicySpec:
    """A picklable recipe for an evaluation policy, built once in every worker.

    Attributes:
        method: one of :data:`METHODS`.
        checkpoint: run dir / checkpoint folder / ``model.safetensors`` / ``pretrained:NAME`` (shipped
            weights) for ``navformer`` and ``dt``; a PPO run dir / checkpoint folder for ``dsac`` and
            ``matdn``.
        seed: base seed of stochastic policies (VRW, FCA's noise); each episode adds its own seed.
        device: where ``navformer`` / ``dt`` run their model (``cpu``, ``cuda``, ``cuda:N``, ``auto``); the
            other methods ignore it (``dsac`` / ``matdn`` run their small networks on the CPU).
        context_steps: ``navformer`` / ``dt`` only: the timesteps the policy attends to
            (``NavFormerPolicy(context_steps=)``, 1 to the model's window); None, the default: the window the
            checkpoint was trained on (``data.context_steps``) when set, else the model's whole context (the
            paper's).
    """

    method: str
    checkpoint: str | None = None
    seed: int = 0
    factory: Callable[[], Any] | None = None
    """For your own policy: a picklable zero-argument callable (e.g. a module-level function) returning a
    ``TensorDictModuleBase`` that writes ``("agents", "action")``; ``method`` is then its label."""
    device: str = "cpu"
    native: bool | None = None
    """``NavFormerPolicy(native=)`` of ``navformer`` / ``dt``: the harness fixes it to what ``validate`` found
    (``transformer_step``), so that every worker runs the same transformer path or fails saying why."""
    context_steps: int | None = None

    def validate(self, label: str | None = None) -> dict[str, Any]:
        """Check the method, (by loading it) the checkpoint, and that ``label`` (default: the method) names no
        training ablation the checkpoint was not trained with (:func:`label_ablation_problem`; ValueError);
        returns a description for ``run.json`` (``model_config``, ``checkpoint_sha256`` and the checkpoint's
        training ``ablation`` for ``navformer`` / ``dt``)."""
        check_device(self.device, "device (--device)")
        if self.factory is not None:
            if self.checkpoint is not None:
                raise ValueError("a policy factory takes no checkpoint; load it inside the factory")
            if self.context_steps is not None:
                raise ValueError(
                    f"context_steps={self.context_steps!r} with a policy factory: build your policy with it "
                    "(NavFormerPolicy(model, context_steps=...)) inside the factory"
                )
            if self.device != "cpu":
                raise ValueError(
                    f"device={self.device!r} with a policy factory: your factory places its own model (e.g. "
                    "return NavFormerPolicy(model.to('cuda'))); leave device at 'cpu'"
                )
            # your own policy: nothing to check a label against
            return {
                "factory": (
                    f"{getattr(self.factory, '__module__', '?')}."
                    f"{getattr(self.factory, '__qualname__', self.factory)}"
                )
            }
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; expected one of {', '.join(METHODS)}")
        if self.context_steps is not None and self.method not in CHECKPOINT_METHODS:
            raise ValueError(
                f"context_steps={self.context_steps!r} (--context-steps) applies to navformer and dt, whose "
                f"transformer has a context; method {self.method!r} has none"
            )
        description: dict[str, Any] = {}
        if self.method in ONLINE_METHODS:
            description = self._validate_online()
        elif self.method in CHECKPOINT_METHODS:
            if self.checkpoint is None:
                raise ValueError(
                    f"method {self.method!r} needs a checkpoint: a run directory, a checkpoint folder or "
                    f"shipped weights pretrained:{self.method} (CLI --checkpoint PATH, "
                    "recipe checkpoint=PATH)"
                )
            from navformer_rl.training.checkpoint import WEIGHTS_FILENAME, resolve_checkpoint

            policy, config = self._load_checkpoint()  # on the CPU: this process only checks it
            weights = resolve_checkpoint(self.checkpoint) / WEIGHTS_FILENAME
            description = {
                "model_config": {k: getattr(config, k) for k in config.__dataclass_fields__},
                "checkpoint_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(),
                "ablation": checkpoint_ablation(self.checkpoint),
                # an inference option, not the paper's: recorded only when the policy uses one (given, or the
                # window the checkpoint was trained on)
                **({} if policy.context_steps is None else {"context_steps": policy.context_steps}),
                # the transformer-step path: the compiled kernel or torch, equal results up to float rounding
                **policy.describe(resolve_device(self.device)),
            }
        elif self.checkpoint is not None:
            raise ValueError(f"method {self.method!r} takes no checkpoint (got {self.checkpoint!r})")
        problem = label_ablation_problem(
            label or self.method,
            self.method,
            description.get("ablation"),
            description.get("model_config"),
            self.checkpoint,
        )
        if problem is not None:
            raise ValueError(problem)
        return description

    def _validate_online(self) -> dict[str, Any]:
        """Load a ``dsac`` / ``matdn`` PPO checkpoint once (ValueError / FileNotFoundError saying why not);
        its description for ``run.json``."""
        if self.checkpoint is None:
            raise ValueError(
                f"method {self.method!r} needs a checkpoint: the run directory of `navformer train-ppo "
                f"method={self.method}` or one of its checkpoint folders (CLI --checkpoint PATH)"
            )
        from navformer_rl.baselines.online import load_online_policy
        from navformer_rl.training.checkpoint import WEIGHTS_FILENAME, resolve_checkpoint

        _, config = load_online_policy(self.checkpoint, self.method)
        weights = resolve_checkpoint(self.checkpoint) / WEIGHTS_FILENAME
        return {
            "model_config": {"method": self.method, **config.to_dict()},
            "checkpoint_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(),
        }

    def _load_checkpoint(self):
        """``(NavFormerPolicy on the CPU, NavFormerConfig)`` of ``navformer`` / ``dt`` with this spec's
        ``native`` and ``context_steps`` (ValueError naming a context longer than the model's); without
        ``context_steps``, the window the checkpoint was trained on (``data.context_steps``) or the whole
        context."""
        from navformer_rl.baselines.dt import load_dt_policy
        from navformer_rl.baselines.navformer import load_navformer_policy
        from navformer_rl.modules.decoding.incremental import check_window_steps

        load = load_navformer_policy if self.method == "navformer" else load_dt_policy
        policy, config = load(self.checkpoint)
        policy.native = self.native
        # without context_steps: the loader's, the checkpoint's training window or the whole context
        if self.context_steps is not None:
            check_window_steps(self.context_steps, config.window_steps, "context_steps (--context-steps)")
            policy.context_steps = self.context_steps
        return policy, config

    def build_with_config(self):
        """``(policy, model config or None)``; a ``navformer`` / ``dt`` policy's model on :attr:`device`."""
        if self.factory is not None:
            return self.factory(), None
        if self.method in ONLINE_METHODS:
            from navformer_rl.baselines.online import load_online_policy

            return load_online_policy(self.checkpoint, self.method)  # small CNNs: on the CPU, beside the env
        if self.method in CHECKPOINT_METHODS:
            policy, config = self._load_checkpoint()
            return policy.to(resolve_device(self.device)), config
        if self.method == "vrw":
            from navformer_rl.baselines.random_walk import RandomWalkPolicy

            return RandomWalkPolicy(seed=self.seed), None
        if self.method == "fca":
            from navformer_rl.baselines.fca import FCAPolicy

            return FCAPolicy(), None
        if self.method == "frontier":
            from navformer_rl.baselines.frontier import FrontierPolicy

            return FrontierPolicy(), None
        raise ValueError(f"unknown method {self.method!r}; expected one of {', '.join(METHODS)}")


def checkpoint_ablation(checkpoint: str | os.PathLike) -> str | None:
    """The training ablation (``TrainConfig.ablation``: ``none``, ``no_thsc``, ..., ``dt``) a checkpoint was
    trained with: from the training config stored in its ``config.json``, else from the run directory's
    ``train_config.json``; None when neither records it (a checkpoint written by hand)."""
    from navformer_rl.training.checkpoint import (
        CHECKPOINTS_DIRNAME,
        read_checkpoint_config,
        resolve_checkpoint,
    )

    train_config = read_checkpoint_config(checkpoint).get("train_config")
    ablation = train_config.get("ablation") if isinstance(train_config, dict) else None
    folder = resolve_checkpoint(checkpoint)
    run_config = folder.parent.parent / TRAIN_CONFIG_FILENAME
    if ablation is None and folder.parent.name == CHECKPOINTS_DIRNAME and run_config.is_file():
        try:
            ablation = json.loads(run_config.read_text()).get("ablation")
        except (ValueError, AttributeError):
            ablation = None
    return ablation if isinstance(ablation, str) else None


ARCHITECTURE_FIELDS = ("encoder", "use_static_encoder", "use_general_encoder", "thsc")
"""The ``NavFormerConfig`` fields a model-level ablation changes (checked when a checkpoint does not record
its training ablation)."""


def label_ablation_problem(
    label: str,
    method: str,
    ablation: str | None,
    model_config: dict[str, Any] | None,
    checkpoint: str | os.PathLike | None = None,
) -> str | None:
    """Why ``label`` misnames the evaluated model, or None when it does not.

    A label that names a training ablation (:func:`~navformer_rl.tasks.label_ablation`:
    ``navformer-no_thsc``) is compared in reports with that ablation's Table IV row, so it must be a
    ``navformer`` / ``dt`` checkpoint trained with that ablation: ``ablation`` (the checkpoint's
    ``TrainConfig.ablation``) must be the named one; when the checkpoint does not record it, its
    ``model_config`` must at least have that ablation's architecture (:data:`ARCHITECTURE_FIELDS`). Labels
    that name no ablation (``navformer-seed1``) are free. A label that starts with another method's name
    (``--method vrw --label navformer``) is refused too: reports take the paper column from that name.
    """
    prefix = label.lower().split("-")[0].split("_")[0]
    if prefix in METHODS and prefix != method:
        return (
            f"the label {label!r} names the method {prefix!r} (reports compare it with that method's paper "
            f"numbers), but the evaluated method is {method!r}; choose a label that starts with {method!r} "
            "or names no method"
        )
    named = label_ablation(label)
    if named is None:
        return None
    row = ABLATION_TO_TABLE4[named]
    claim = f"the label {label!r} names the training ablation {named!r} (compared with Table IV's {row!r})"
    fix = (
        f"evaluate the checkpoint trained with ablation={named}, or choose a label that names no ablation "
        "(e.g. navformer-seed1)"
    )
    where = f"checkpoint {checkpoint}" if checkpoint is not None else "the checkpoint"
    if ablation is not None:
        if ablation != named:
            return f"{claim}, but {where} was trained with ablation={ablation}; {fix}"
        return None
    if model_config is None:
        return None
    from navformer_rl.training import TrainConfig
    from navformer_rl.training import model_config as ablation_model

    expected = ablation_model(TrainConfig(ablation=named))
    differ = {
        name: (model_config.get(name), getattr(expected, name))
        for name in ARCHITECTURE_FIELDS
        if model_config.get(name) != getattr(expected, name)
    }
    if differ:
        return (
            f"{claim}, but {where} records no training ablation and its model lacks that ablation's "
            f"architecture ((checkpoint, {named}): {differ}); {fix}"
        )
    return None
