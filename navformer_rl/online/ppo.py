"""PPO from TorchRL's parts: ``make_collector``, ``make_loss`` (``ClipPPOLoss`` + ``GAE``),
``make_optimizer``, and one batch's advantage and update (:func:`robot_steps`, :func:`ppo_update`).

A collected batch is ``[T]`` env steps (one worker) or ``[W, T]`` (``W`` workers, a lazy stack when their
robot counts differ), each step holding ``A`` robots under ``"agents"``. GAE runs per worker over time with
each robot's own done flags (``("next", "agents", "done")``: the robot succeeded or the episode was
truncated; ``terminated``: it succeeded, so no bootstrap). The update then sees a flat batch of robot-steps:
the steps of robots still searching (a robot that has succeeded is parked and its later steps are dropped).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from navformer_rl.baselines.actor_critic import (
    ACTION_KEY,
    AGENTS,
    FEATURES_KEY,
    LOG_PROB_KEY,
    VALUE_KEY,
    ActorCriticNet,
)
from navformer_rl.online.config import LossConfig, OptimConfig
from navformer_rl.online.reward import REWARD_KEY

ADVANTAGE_KEY = (AGENTS, "advantage")
VALUE_TARGET_KEY = (AGENTS, "value_target")
DONE_KEY = (AGENTS, "done")
TERMINATED_KEY = (AGENTS, "terminated")
LOSS_TERMS = ("loss_objective", "loss_critic", "loss_entropy")


def make_loss(net: ActorCriticNet, cfg: LossConfig) -> ClipPPOLoss:
    """``ClipPPOLoss`` on the net's actor and critic (shared trunk, run once per minibatch: the critic reuses
    the actor's features) with a ``GAE`` value estimator, keys set to the ``"agents"`` group."""
    loss = ClipPPOLoss(
        net.actor(),
        net.critic(reuse_features=True),
        clip_epsilon=cfg.clip_epsilon,
        entropy_coeff=cfg.entropy_coeff,
        critic_coeff=cfg.critic_coeff,
        loss_critic_type=cfg.loss_critic_type,
        normalize_advantage=cfg.normalize_advantage,
    )
    loss.set_keys(
        action=ACTION_KEY,
        sample_log_prob=LOG_PROB_KEY,
        value=VALUE_KEY,
        advantage=ADVANTAGE_KEY,
        value_target=VALUE_TARGET_KEY,
        reward=REWARD_KEY,
        done=DONE_KEY,
        terminated=TERMINATED_KEY,
    )
    # deactivate_vmap: the value net runs as is (vmap has no batching rule for CPU flash attention)
    loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.gamma, lmbda=cfg.lmbda, deactivate_vmap=True)
    return loss


def make_optimizer(loss: ClipPPOLoss, cfg: OptimConfig) -> torch.optim.Adam:
    """Adam over the loss's parameters (actor and critic, the shared trunk once)."""
    return torch.optim.Adam(loss.parameters(), lr=cfg.lr, eps=1e-5)


def make_collector(
    env_factories: Sequence,
    policy,
    frames_per_batch: int,
):
    """One factory: a ``Collector`` in this process; several: a ``MultiSyncCollector`` with one worker
    process per factory (``frames_per_batch`` split evenly; a lazy stack of the workers' ``[T]`` batches
    when their robot counts differ). Frames are counted by the caller (no total)."""
    from torchrl.collectors import Collector, MultiSyncCollector

    if len(env_factories) == 1:
        return Collector(
            env_factories[0],
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=-1,
            auto_register_policy_transforms=False,
        )
    same_shape = len({factory.n_robots for factory in env_factories}) == 1
    return MultiSyncCollector(
        list(env_factories),
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=-1,
        use_buffers=same_shape,  # different robot counts: the workers' batches are lazily stacked
        cat_results="stack",
        auto_register_policy_transforms=False,
    )


_UPDATE_KEYS = (
    "pixels",
    "target_pixels",
    "step_count",
    "memory",
    "memory_mask",
    "action",
    "action_log_prob",
    "advantage",
    "value_target",
    "state_value",
)


def worker_batches(data: TensorDictBase) -> list[TensorDictBase]:
    """The collector's output as a list of ``[T]`` batches, one per worker."""
    return list(data.unbind(0)) if data.batch_dims == 2 else [data]


@torch.no_grad()
def robot_steps(loss: ClipPPOLoss, data: TensorDictBase) -> TensorDictBase:
    """GAE on every worker batch of ``data``, then the steps of robots still searching as one flat batch.

    Returns a ``[N]`` tensordict whose ``"agents"`` entries hold no robot dimension: the policy inputs,
    ``action``, ``action_log_prob``, ``state_value``, ``advantage`` and ``value_target``.
    """
    parts = []
    for batch in worker_batches(data):
        # the values come from the trunk, never from features the collector's policy wrote
        batch = batch.clone(False).exclude(FEATURES_KEY)
        loss.value_estimator(
            batch, params=loss.critic_network_params, target_params=loss.target_critic_network_params
        )
        agents = batch.get(AGENTS)
        keep = [k for k in _UPDATE_KEYS if k in agents.keys()]
        flat = agents.select(*keep).reshape(-1)
        searching = ~agents.get("done").reshape(-1)  # done before the step: parked after success
        parts.append(flat[searching])
    steps = torch.cat(parts) if len(parts) > 1 else parts[0]
    return TensorDict({AGENTS: steps}, batch_size=steps.batch_size)


def ppo_update(
    loss: ClipPPOLoss,
    optimizer: torch.optim.Optimizer,
    steps: TensorDictBase,
    cfg: OptimConfig,
    generator: torch.Generator | None = None,
) -> dict[str, float]:
    """``cfg.epochs`` passes of ``ClipPPOLoss`` over ``steps`` (:func:`robot_steps`) in shuffled minibatches
    of ``cfg.minibatch_size`` robot-steps; each minibatch: loss_objective + loss_critic + loss_entropy (the
    forward under autocast when ``cfg.autocast_dtype`` is set) -> backward -> clip the gradient norm to
    ``cfg.max_grad_norm`` -> Adam step.

    Returns the mean of each loss term and of ``entropy``, ``kl_approx``, ``clip_fraction`` and
    ``grad_norm`` over the minibatches.
    """
    n = steps.shape[0]
    if n == 0:
        return {}
    dtype = None if cfg.autocast_dtype is None else getattr(torch, cfg.autocast_dtype)
    device_type = next(loss.parameters()).device.type
    size = min(cfg.minibatch_size, n)
    per_epoch = max(n // size, 1)
    totals: dict[str, float] = {}
    count = 0
    for _ in range(cfg.epochs):
        order = torch.randperm(n, generator=generator)
        for start in range(0, per_epoch * size, size):
            minibatch = steps[order[start : start + size]]
            with torch.autocast(device_type, dtype=dtype, enabled=dtype is not None):
                out = loss(minibatch)
            terms = [term for term in LOSS_TERMS if term in out.keys()]  # no critic with critic_coeff 0
            total = sum(out.get(term) for term in terms)
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(loss.parameters(), cfg.max_grad_norm)
            optimizer.step()
            logged = {
                k: out.get(k) for k in (*terms, "entropy", "kl_approx", "clip_fraction") if k in out.keys()
            }
            logged["grad_norm"] = grad_norm
            for key, value in logged.items():
                totals[key] = totals.get(key, 0.0) + float(value.detach().mean())
            count += 1
    return {key: value / count for key, value in totals.items()}


def linear_lr(base_lr: float, frames: int, total_frames: int) -> float:
    """Linearly annealed learning rate: ``base_lr`` at frame 0, 0 at ``total_frames`` (kept above 0)."""
    return base_lr * max(1.0 - frames / total_frames, 1e-3) if total_frames > 0 else base_lr


def finished_episode_stats(data: TensorDictBase, return_key, success_key) -> tuple[list[float], list[float]]:
    """Per-robot returns and successes (1.0 / 0.0) of the episodes that ended in ``data`` (root
    ``("next", "done")``), read from ``return_key`` / ``success_key`` under ``"next"``."""
    returns: list[float] = []
    successes: list[float] = []
    for batch in worker_batches(data):
        ended = batch.get(("next", "done")).reshape(-1)
        if not bool(ended.any()):
            continue
        returns.extend(batch.get(("next", *return_key))[ended].reshape(-1).tolist())
        successes.extend(batch.get(("next", *success_key))[ended].reshape(-1).float().tolist())
    return returns, successes


def mean_or_nan(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else math.nan
