"""``train_ppo(PPOConfig)``: DSAC or MA-TDN trained online with PPO, with checkpoints, resume and a CSV log.

The loop, top to bottom::

    net = build_net(method)                          # trunk + Gaussian policy head + value head
    loss = make_loss(net)                            # ClipPPOLoss + GAE, keys under "agents"
    collector = make_collector(env factories, net.actor())
    for data in collector:                           # [W, T] env steps, A robots each
        steps = robot_steps(loss, data)              # GAE per worker, then the searching robots' steps
        ppo_update(loss, optimizer, steps)           # epochs x minibatches of ClipPPOLoss
        collector.update_policy_weights_()
        log a row; every eval.interval batches the fixed episodes; every checkpoint.interval a checkpoint

A run directory holds ``ppo_config.json``, ``progress.csv``
(:data:`~navformer_rl.online.curve.PROGRESS_COLUMNS`), ``learning_curve.png`` and ``checkpoints/`` (the house
layout: ``config.json`` + ``model.safetensors``, which ``navformer evaluate --method dsac|matdn`` reads, and
``resume.pt`` with the optimiser, counters and RNG states). Resuming restores weights, optimiser, counters and
RNG states; episodes in flight are not restored (the collector starts new ones, with env seeds derived from
the seed and the resumed iteration).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from navformer_rl.online.config import PPOConfig, model_config, validate_ppo_config

CONFIG_FILENAME = "ppo_config.json"


@dataclass
class PPOResult:
    """What :func:`train_ppo` returns."""

    run_dir: Path
    iterations: int
    frames: int
    metrics: dict[str, float]
    checkpoint: Path | None

    def summary(self) -> str:
        shown = ", ".join(
            f"{k}={self.metrics[k]:.4g}"
            for k in ("train_return", "train_success_rate", "eval_success_rate")
            if k in self.metrics and not math.isnan(self.metrics[k])
        )
        head = f"trained {self.iterations} PPO batches, {self.frames} env frames" + (
            f"; {shown}" if shown else ""
        )
        return f"{head}\nrun directory: {self.run_dir}\ncheckpoint:    {self.checkpoint}"


def _env_factories(cfg: PPOConfig, model_cfg: Any, round_: int) -> list:
    from navformer_rl.online.envs import EnvFactory, worker_seed
    from navformer_rl.online.reward import RewardWeights

    env = cfg.env
    reward = RewardWeights(**cfg.reward.__dict__)
    kwargs = (
        ("kind", env.kind),
        ("max_steps", env.max_steps),
        ("episodes_per_world", env.episodes_per_world),
        ("textured", env.textured),
    )
    return [
        EnvFactory(
            cfg.method,
            model_cfg,
            tuple(env.sizes),
            env.robot_counts[i % len(env.robot_counts)],
            reward,
            worker_seed(cfg.seed, i, round_),
            kwargs,
        )
        for i in range(cfg.collector.num_workers)
    ]


def _eval_env(cfg: PPOConfig, model_cfg: Any):
    from navformer_rl.baselines.online import env_primers
    from navformer_rl.online.envs import make_env
    from navformer_rl.online.reward import RewardWeights

    return make_env(
        cfg.env.sizes,
        cfg.eval.n_robots,
        reward=RewardWeights(**cfg.reward.__dict__),
        primers=env_primers(cfg.method, model_cfg, cfg.eval.n_robots),
        kind=cfg.env.kind,
        max_steps=cfg.eval.max_steps,
        textured=cfg.env.textured,
    )


def _check_resumable(cfg: PPOConfig, stored: dict[str, Any], checkpoint: Path) -> None:
    """The resumed run must train the same method and model as its checkpoint."""
    from navformer_rl.baselines.online import checkpoint_model_config

    expected = checkpoint_model_config(cfg.method, model_config(cfg))
    if stored != expected:
        raise ValueError(
            f"resume: checkpoint {checkpoint} holds model {stored}, but the configuration builds {expected}; "
            "resume with the run's own method and model settings"
        )


def train_ppo(cfg: PPOConfig) -> PPOResult:
    """Train ``cfg.method`` with PPO until ``cfg.collector.total_frames`` env frames (module docstring).

    Raises ValueError for a bad configuration, FileExistsError for a fresh run into a folder that already
    holds checkpoints (set ``resume=true`` to continue it).
    """
    validate_ppo_config(cfg)
    import torch

    from navformer_rl.baselines.online import OnlinePolicy, build_net, checkpoint_model_config
    from navformer_rl.online.curve import (
        CURVE_FILENAME,
        ProgressLog,
        fixed_episode_eval,
        plot_learning_curves,
    )
    from navformer_rl.online.envs import EPISODE_RETURN_KEY
    from navformer_rl.online.ppo import (
        finished_episode_stats,
        linear_lr,
        make_collector,
        make_loss,
        make_optimizer,
        mean_or_nan,
        ppo_update,
        robot_steps,
    )
    from navformer_rl.training import checkpoint as ckpt
    from navformer_rl.utils.durable import atomic_write_text

    run_dir = Path(cfg.output_dir)
    latest = ckpt.run_folder_latest(run_dir, cfg.resume)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    model_cfg = model_config(cfg)

    # ---------------------------------------------------------------- model, loss, optimiser
    torch.manual_seed(cfg.seed)
    net = build_net(cfg.method, model_cfg)
    loss = make_loss(net, cfg.loss)
    optimizer = make_optimizer(loss, cfg.optim)
    iteration = frames = robot_frames = episodes = 0
    if latest is not None:
        stored, state = ckpt.load_model_state(latest)
        _check_resumable(cfg, stored, latest)
        net.load_state_dict(state)
        resume = ckpt.load_resume_state(latest)
        optimizer.load_state_dict(resume["optimizer"])
        iteration, frames = int(resume["iteration"]), int(resume["frames"])
        robot_frames, episodes = int(resume["robot_frames"]), int(resume["episodes"])
        ckpt.restore_rng_state(resume["rng"])
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / CONFIG_FILENAME, json.dumps(cfg.to_dict(), indent=2, sort_keys=True) + "\n")
    log = ProgressLog(run_dir, resume_iteration=iteration)
    stored_model = checkpoint_model_config(cfg.method, model_cfg)

    def save() -> Path:
        return ckpt.save_checkpoint(
            run_dir,
            iteration,
            model_state=net.state_dict(),
            model_config=stored_model,
            train_config=cfg.to_dict(),
            resume_state={
                "optimizer": optimizer.state_dict(),
                "iteration": iteration,
                "frames": frames,
                "robot_frames": robot_frames,
                "episodes": episodes,
                "rng": ckpt.capture_rng_state(),
            },
            keep_last=cfg.checkpoint.keep_last,
        )

    if frames >= cfg.collector.total_frames:  # a finished run: nothing to do
        return PPOResult(run_dir, iteration, frames, {}, latest)

    # ---------------------------------------------------------------- collector, evaluation env
    collector = make_collector(
        _env_factories(cfg, model_cfg, iteration), net.actor(), cfg.collector.frames_per_batch
    )
    eval_env = _eval_env(cfg, model_cfg) if cfg.eval.interval else None
    eval_policy = OnlinePolicy(net)
    metrics: dict[str, float] = {}
    last_checkpoint: Path | None = latest
    try:
        started = time.perf_counter()
        for data in collector:
            collected = time.perf_counter()
            # ------------------------------------------------------------ the PPO step
            lr = cfg.optim.lr
            if cfg.optim.anneal_lr:
                lr = linear_lr(cfg.optim.lr, frames, cfg.collector.total_frames)
            for group in optimizer.param_groups:
                group["lr"] = lr
            steps = robot_steps(loss, data)
            net.train()
            stats = ppo_update(loss, optimizer, steps, cfg.optim)
            collector.update_policy_weights_()
            updated = time.perf_counter()
            # ------------------------------------------------------------ counters and log row
            iteration += 1
            frames += data.numel()
            robot_frames += steps.shape[0]
            returns, successes = finished_episode_stats(data, EPISODE_RETURN_KEY, ("privileged", "success"))
            episodes += int(data.get(("next", "done")).sum())
            metrics = {
                "iteration": iteration,
                "frames": frames,
                "robot_frames": robot_frames,
                "episodes": episodes,
                "train_return": mean_or_nan(returns),
                "train_success_rate": mean_or_nan(successes),
                "eval_return": math.nan,
                "eval_success_rate": math.nan,
                **stats,
                "lr": lr,
                "collect_seconds": collected - started,
                "update_seconds": updated - collected,
                "frames_per_second": data.numel() / max(updated - started, 1e-9),
            }
            last = frames >= cfg.collector.total_frames
            if eval_env is not None and (iteration % cfg.eval.interval == 0 or last):
                net.eval()
                result = fixed_episode_eval(
                    eval_policy, eval_env, cfg.eval.episodes, cfg.env.sizes, cfg.eval.seed, cfg.eval.max_steps
                )
                metrics["eval_return"] = result["return"]
                metrics["eval_success_rate"] = result["success_rate"]
            log.append(metrics)
            if iteration % cfg.checkpoint.interval == 0 or last:
                last_checkpoint = save()
                plot_learning_curves({"": log.path}, run_dir / CURVE_FILENAME, f"{cfg.method} + PPO")
            if last:
                break
            started = time.perf_counter()
    finally:
        collector.shutdown()
        if eval_env is not None:
            eval_env.close()
    return PPOResult(run_dir, iteration, frames, metrics, last_checkpoint)
