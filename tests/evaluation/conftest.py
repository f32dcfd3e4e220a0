"""Tiny episode sets for the evaluation tests (7.5 m maze, 2 Jackals, a few steps)."""

import dataclasses

import pytest
import torch

from navformer_rl.evaluation.episodes import Setup, make_episode_set
from navformer_rl.evaluation.harness import evaluate
from navformer_rl.modules import NavFormerConfig, NavFormerModel
from navformer_rl.training.checkpoint import save_checkpoint

TINY_SETUP = Setup("7.5m-2r", 7.5, ("jackal", "jackal"), (True, True))


@pytest.fixture(scope="session")
def tiny_episodes():
    """Two trials in one 7.5 m maze, 12 steps each."""
    return make_episode_set(
        [TINY_SETUP], trials_per_setup=2, trials_per_world=2, seed=1, name="tiny", max_steps=12
    )


@pytest.fixture(scope="session")
def vrw_run(tmp_path_factory, tiny_episodes):
    """VRW (seed 3) on the tiny episodes with a map and a video of the first: ``(out_dir, result)``."""
    out = tmp_path_factory.mktemp("eval") / "vrw"
    result = evaluate("vrw", tiny_episodes, out, maps_per_setup=1, videos_per_setup=1, progress=False, seed=3)
    return out, result


def make_checkpoint(run_dir, config, train_config=None):
    """A seeded, untrained checkpoint of ``config`` in ``run_dir`` (``train_config`` stored in its header)."""
    torch.manual_seed(0)
    model = NavFormerModel(config)
    state = model.state_dict()
    save_checkpoint(
        run_dir,
        1,
        model_state=state,
        model_config=dataclasses.asdict(config),
        train_config=train_config or {},
        resume_state=None,
    )
    return run_dir


@pytest.fixture(scope="session")
def checkpoint_factory():
    """:func:`make_checkpoint`: ``(run_dir, config, train_config=None) -> run_dir``."""
    return make_checkpoint


@pytest.fixture(scope="session")
def checkpoints(tmp_path_factory):
    """Untrained (seeded) NavFormer and DT-baseline checkpoints: ``{"navformer": dir, "dt": dir}``."""
    root = tmp_path_factory.mktemp("ckpt")
    return {
        "navformer": make_checkpoint(root / "navformer", NavFormerConfig()),
        "dt": make_checkpoint(root / "dt", NavFormerConfig.dt_baseline()),
    }


class FakeClock:
    """Stands in for the ``time`` module of the code under test: ``perf_counter`` returns ``now``, which
    the test advances by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now


@pytest.fixture
def fake_clock() -> FakeClock:
    """A :class:`FakeClock` at 0 s; the test patches it in as the ``time`` of the module it times."""
    return FakeClock()
