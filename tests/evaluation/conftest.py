"""Tiny episode sets for the evaluation tests (7.5 m maze, 2 Jackals, a few steps)."""

import pytest

from navformer_rl.evaluation.episodes import Setup, make_episode_set
from navformer_rl.evaluation.harness import evaluate

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
