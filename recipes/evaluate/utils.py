"""Factories of the evaluation recipe; all work happens in :mod:`navformer_rl.evaluation`."""

from __future__ import annotations

from omegaconf import DictConfig

from navformer_rl.evaluation.episodes import EpisodeSet, load_episode_set, make_protocol_episodes
from navformer_rl.evaluation.harness import EvaluationResult, PolicySpec, evaluate


def make_episode_set(cfg: DictConfig) -> EpisodeSet:
    """The episode set: ``cfg.episodes`` (a file) if given, else the episodes of ``cfg.protocol``.

    The method and checkpoint are validated first, so a bad one fails before episode generation.
    """
    PolicySpec(cfg.method, cfg.checkpoint, int(cfg.seed)).validate()
    if cfg.episodes:
        return load_episode_set(cfg.episodes)
    return make_protocol_episodes(
        cfg.protocol,
        int(cfg.trials_per_setup),
        int(cfg.trials_per_world),
        int(cfg.episode_seed),
        int(cfg.max_steps),
    )


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
