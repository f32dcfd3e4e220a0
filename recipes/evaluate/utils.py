"""Factories of the evaluation recipe; all work happens in :mod:`navformer_rl.evaluation`."""

from __future__ import annotations

from omegaconf import DictConfig

from navformer_rl.constants import MAX_EPISODE_STEPS
from navformer_rl.evaluation.episodes import (
    PAPER_TRIALS_PER_SETUP,
    PAPER_TRIALS_PER_WORLD,
    EpisodeSet,
    load_episode_set,
    make_protocol_episodes,
)
from navformer_rl.evaluation.harness import EvaluationResult, PolicySpec, evaluate

GENERATION_DEFAULTS = {
    "trials_per_setup": PAPER_TRIALS_PER_SETUP,
    "trials_per_world": PAPER_TRIALS_PER_WORLD,
    "episode_seed": 0,
    "max_steps": MAX_EPISODE_STEPS,
}
"""The config keys that shape generated episodes (in ``make_protocol_episodes``' order), with the value a
null gets."""


def make_episode_set(cfg: DictConfig) -> EpisodeSet:
    """The episode set: ``cfg.episodes`` (a file) if given, else the episodes of ``cfg.protocol``.

    The method and checkpoint are validated first, so a bad one fails before episode generation.
    """
    PolicySpec(cfg.method, cfg.checkpoint, int(cfg.seed)).validate()
    generation = {name: cfg[name] for name in GENERATION_DEFAULTS}
    if cfg.episodes:
        given = [name for name, value in generation.items() if value is not None]
        if given:
            raise ValueError(
                f"{', '.join(given)}: only with `protocol`; the episode file {cfg.episodes} fixes its trials, "
                "seeds and steps per trial"
            )
        return load_episode_set(cfg.episodes)
    values = [int(GENERATION_DEFAULTS[n] if v is None else v) for n, v in generation.items()]
    return make_protocol_episodes(cfg.protocol, *values)


def run_evaluation(cfg: DictConfig, episode_set: EpisodeSet) -> EvaluationResult:
    """Run the harness with the recipe's settings into ``cfg.output_dir``."""
    return evaluate(
        cfg.method,
        episode_set,
        cfg.output_dir,
        checkpoint=cfg.checkpoint,
        workers=int(cfg.workers),
        label=cfg.label,
        seed=int(cfg.seed),
        maps_per_setup=int(cfg.maps_per_setup),
        videos_per_setup=int(cfg.videos_per_setup),
        progress=bool(cfg.progress),
        resume=bool(cfg.resume),
    )
