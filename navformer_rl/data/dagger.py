"""DAgger's policy in the collection loop (Ross et al., "A Reduction of Imitation Learning and Structured
Prediction to No-Regret Online Learning", AISTATS 2011; not in the paper).

Round i of DAgger drives the robots with the mixture pi_i = beta pi* + (1 - beta) pi_hat_i of the expert pi*
and the trained policy pi_hat_i, and labels every visited state with the expert's action; training on the
aggregate of all rounds' data then covers the states the policy itself reaches (e.g. up against a wall),
which plain expert data never show. Here the mixture is drawn per robot and per step (:class:`DaggerMixture`)
from a seeded stream of the work unit (:func:`~navformer_rl.data.collect_settings.mixing_generator`), so a
collection stays deterministic, resumable and independent of the number of workers.

The policy is a NavFormer or DT checkpoint run by :class:`~navformer_rl.modules.inference.NavFormerPolicy` on
the CPU, batched over the robots of an episode, its context its own past actions, on the window the checkpoint
was trained on (as deployed: ``navformer evaluate``'s default). Each worker
process loads it once (:func:`policy_for`) and checks the weights' sha256 against the collection's settings.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.data.collect_settings import DaggerSettings
from navformer_rl.utils.checks import check_number

if TYPE_CHECKING:
    from navformer_rl.envs.world import WorldSpec
    from navformer_rl.modules.inference import NavFormerPolicy


def dagger_settings(checkpoint: str, beta: float = 0.5) -> DaggerSettings:
    """The :class:`DaggerSettings` of the policy at ``checkpoint`` (a run directory, a checkpoint folder or
    file, or ``pretrained:NAME``: anything ``navformer evaluate --checkpoint`` takes) mixed with ``beta``.

    Loads the model once to check that it is a NavFormer / DT checkpoint, hashes its weights, and fixes the
    transformer-step path (the compiled kernel where it runs here, else torch) that every worker then uses.

    Raises:
        FileNotFoundError / ValueError: no checkpoint there, or not one of ours (one line naming the path),
            or ``beta`` outside [0, 1].
    """
    from navformer_rl.modules.inference import NavFormerPolicy
    from navformer_rl.training.checkpoint import (
        WEIGHTS_FILENAME,
        load_policy_model,
        resolve_checkpoint,
        training_context_steps,
    )
    from navformer_rl.training.pretrained_registry import file_sha256

    check_number(beta, "dagger beta", at_least=0.0, at_most=1.0)
    folder = resolve_checkpoint(checkpoint)
    _, model = load_policy_model(folder)
    step = NavFormerPolicy(model).describe(torch.device("cpu"))["transformer_step"]
    return DaggerSettings(
        checkpoint=str(folder.resolve()),
        weights_sha256=file_sha256(folder / WEIGHTS_FILENAME),
        beta=float(beta),
        transformer_step=step,
        context_steps=training_context_steps(folder),
    )


@functools.lru_cache(maxsize=2)
def _cached_policy(
    folder: str, weights_sha256: str, native: bool, context_steps: int | None
) -> NavFormerPolicy:
    from navformer_rl.modules.inference import NavFormerPolicy
    from navformer_rl.training.checkpoint import WEIGHTS_FILENAME, load_policy_model
    from navformer_rl.training.pretrained_registry import file_sha256

    found = file_sha256(Path(folder) / WEIGHTS_FILENAME)
    if found != weights_sha256:
        raise ValueError(
            f"{Path(folder) / WEIGHTS_FILENAME} changed since the collection started (sha256 "
            f"{found[:12]}..., the dataset's settings record {weights_sha256[:12]}...): restore those "
            "weights, or collect into a new folder"
        )
    _, model = load_policy_model(folder)
    return NavFormerPolicy(
        model,
        pixels_key="pixels",
        target_pixels_key="target_pixels",
        step_count_key=None,
        reward_key=None,
        action_key="action",
        is_init_key=None,
        native=native,
        context_steps=context_steps,
    )


def policy_for(settings: DaggerSettings) -> NavFormerPolicy:
    """The policy of ``settings``, loaded once per process (its weights' sha256 checked; ``ValueError`` when
    the file changed since :func:`dagger_settings`)."""
    return _cached_policy(
        settings.checkpoint,
        settings.weights_sha256,
        settings.transformer_step == "native",
        settings.context_steps,
    )


class DaggerMixture:
    """One episode's mixture of the expert and the policy, for every robot of the simulator.

    Args:
        policy: the :class:`~navformer_rl.modules.inference.NavFormerPolicy` (reads ``pixels`` /
            ``target_pixels`` uint8 ``[R, 84, 84, 3]``, writes ``action`` float32 ``[R, 2]``); its episode
            state is reset here.
        beta: probability of executing the expert's action at a step.
        world: the episode's world (robot ``i``'s target image is that of ``world.targets[i]``).
        rng: the episode's mixing stream (one uniform draw per robot per step, whoever is active).
    """

    def __init__(self, policy: NavFormerPolicy, beta: float, world: WorldSpec, rng: np.random.Generator):
        from navformer_rl.envs.target_image import render_target_image

        self.policy = policy
        self.beta = float(beta)
        self.rng = rng
        self.targets = torch.from_numpy(
            np.stack([render_target_image(t.shape, t.color) for t in world.targets[: world.n_robots]])
        )
        policy.reset()

    def executed(self, sim, expert_actions: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(executed float32 [R, 2], from_policy bool [R])`` for this step: each robot's expert action
        (``expert_actions`` float32 ``[R, 2]``) when its draw ``u < beta``, else the policy's on the robot's
        current camera frame (rendered now for the ``active`` robots; zeros for the others, whose actions are
        not executed). The policy runs every step for every robot, so its context is its own actions."""
        R = sim.n_robots
        frames = torch.from_numpy(sim.render_all(active))
        td = TensorDict({"pixels": frames, "target_pixels": self.targets}, batch_size=[R])
        with torch.no_grad():
            action = self.policy(td)["action"].numpy().astype(np.float32)
        from_policy = self.rng.random(R) >= self.beta
        executed = np.where(from_policy[:, None], np.clip(action, -1.0, 1.0), expert_actions)
        return executed.astype(np.float32), from_policy & active


def dagger_mixture(settings: DaggerSettings, world: WorldSpec, rng: np.random.Generator) -> DaggerMixture:
    """A :class:`DaggerMixture` of the process's policy of ``settings`` for one episode in ``world``."""
    return DaggerMixture(policy_for(settings), settings.beta, world, rng)
