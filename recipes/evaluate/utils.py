"""Factories of the evaluation recipe; all work happens in :mod:`navformer_rl.evaluation`."""

from __future__ import annotations

import os
import shlex
from collections.abc import Sequence

from omegaconf import DictConfig

from navformer_rl.constants import MAX_EPISODE_STEPS
from navformer_rl.evaluation.episodes import (
    EpisodeSet,
    load_episode_set,
    make_protocol_episodes,
    protocol_trials,
)
from navformer_rl.evaluation.harness import EvaluateConfig, EvaluationResult, PolicySpec, evaluate
from navformer_rl.evaluation.measures import check_cluster
from navformer_rl.utils.backends import check_backend

GENERATION_DEFAULTS = {
    "trials_per_setup": None,
    "trials_per_world": None,
    "episode_seed": 0,
    "max_steps": MAX_EPISODE_STEPS,
}
"""The config keys that shape generated episodes (in ``make_protocol_episodes``' order), with the value a
null gets (None: the protocol's own, :func:`~navformer_rl.evaluation.episodes.protocol_trials`)."""


def check_policy(cfg: DictConfig) -> None:
    """Refuse (ValueError) an unknown method, a missing or unreadable checkpoint, a label naming a training
    ablation the checkpoint was not trained with, an unknown ``cluster`` or ``backend`` (or ``ray`` without
    ray installed) or an unusable ``device``; the recipe calls it first, before it prints the output folder
    and generates episodes (``PolicySpec.validate`` loads the checkpoint)."""
    check_cluster(str(cfg.cluster))
    check_backend(str(cfg.backend))
    PolicySpec(
        cfg.method, cfg.checkpoint, int(cfg.seed), device=str(cfg.device), context_steps=cfg.context_steps
    ).validate(cfg.label)


def make_episode_set(cfg: DictConfig) -> EpisodeSet:
    """The episode set: ``cfg.episodes`` (a file) if given, else the episodes of ``cfg.protocol``."""
    generation = {name: cfg[name] for name in GENERATION_DEFAULTS}
    setups = None if cfg.setups is None else [str(name) for name in cfg.setups]
    if cfg.episodes:
        given = [name for name, value in {**generation, "setups": setups}.items() if value is not None]
        if given:
            raise ValueError(
                f"{', '.join(given)}: only with `protocol`; the episode file {cfg.episodes} fixes its "
                "trials, seeds and steps per trial"
            )
        return load_episode_set(cfg.episodes)
    defaults = {
        **GENERATION_DEFAULTS,
        **dict(zip(("trials_per_setup", "trials_per_world"), protocol_trials(cfg.protocol))),
    }
    values = [int(defaults[n] if v is None else v) for n, v in generation.items()]
    workers = int(cfg.workers)
    if str(cfg.backend) != "local":  # generated here: with Ray, `workers` may count a cluster's CPUs
        workers = min(workers, len(os.sched_getaffinity(0)))
    return make_protocol_episodes(cfg.protocol, *values, workers=workers, setups=setups)


def run_evaluation(cfg: DictConfig, episode_set: EpisodeSet) -> EvaluationResult:
    """Run the harness with the recipe's settings into ``cfg.output_dir``."""
    config = EvaluateConfig(
        checkpoint=cfg.checkpoint,
        workers=int(cfg.workers),
        label=cfg.label,
        seed=int(cfg.seed),
        maps_per_setup=int(cfg.maps_per_setup),
        videos_per_setup=int(cfg.videos_per_setup),
        cluster=str(cfg.cluster),
        device=str(cfg.device),
        progress=bool(cfg.progress),
        resume=bool(cfg.resume),
        backend=str(cfg.backend),
        ray_address=cfg.ray_address,
        context_steps=cfg.context_steps,
    )
    return evaluate(cfg.method, episode_set, cfg.output_dir, config)


def resume_hint(
    output_dir: str, overrides: Sequence[str], script: str = "recipes/evaluate/evaluate.py"
) -> str:
    """What the recipe prints at start: the output folder, and the command that resumes this evaluation.

    The default ``output_dir`` is a new timestamped folder per run, so a plain rerun starts over elsewhere;
    rerunning with ``output_dir=<this folder>`` (and the same settings) reuses its finished episodes.

    Args:
        output_dir: this run's output folder.
        overrides: the command line's overrides (hydra's task overrides); an ``output_dir`` one is replaced.
        script: the recipe's path as it is invoked.
    """
    folder = os.path.abspath(output_dir)
    replaced = ("output_dir", "hydra.run.dir")  # hydra's own folder too: no new timestamped one per resume
    kept = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in replaced]
    pinned = [f"output_dir={folder}", f"hydra.run.dir={folder}"]
    command = " ".join(["python", script, *map(shlex.quote, kept + pinned)])
    return (
        f"output folder: {folder}\n"
        "to resume this evaluation (after an interruption, or to reuse its finished episodes), rerun it into "
        "the same folder (with any --config-name / --config-path you gave):\n"
        f"  {command}"
    )
