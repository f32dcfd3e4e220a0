"""Cross-task trajectory sampling (paper §VI): alternate D_e and D_ca batches each iteration.

``CrossTaskSampler.sample() -> (task, batch)`` where ``task`` is ``"exploration"`` or
``"collision_avoidance"`` and ``batch`` comes from that dataset's :class:`TrajectoryBatcher` (25 trajectories
from D_e, 150 from D_ca by default). The ablations "w/o D_e" / "w/o D_ca" (paper Table IV) pass only one
batcher: every iteration then draws from it.
"""

from __future__ import annotations

from typing import Any

from tensordict import TensorDict

from navformer_rl.data.samplers import TrajectoryBatcher
from navformer_rl.tasks import DATASETS

EXPLORATION = DATASETS["e"].task
COLLISION_AVOIDANCE = DATASETS["ca"].task


class CrossTaskSampler:
    """Alternates between trajectory batchers, starting with exploration when both are present.

    Args:
        exploration: batcher over D_e, or ``None`` (ablation without D_e).
        collision_avoidance: batcher over D_ca, or ``None`` (ablation without D_ca).
    """

    def __init__(self, exploration: TrajectoryBatcher | None, collision_avoidance: TrajectoryBatcher | None):
        self.sources: list[tuple[str, TrajectoryBatcher]] = [
            (name, batcher)
            for name, batcher in ((EXPLORATION, exploration), (COLLISION_AVOIDANCE, collision_avoidance))
            if batcher is not None
        ]
        if not self.sources:
            raise ValueError("CrossTaskSampler needs at least one of exploration / collision_avoidance")
        self.iteration = 0

    @property
    def tasks(self) -> list[str]:
        return [name for name, _ in self.sources]

    def next_task(self) -> str:
        return self.sources[self.iteration % len(self.sources)][0]

    def sample(self) -> tuple[str, TensorDict]:
        name, batcher = self.sources[self.iteration % len(self.sources)]
        self.iteration += 1
        return name, batcher.sample()

    def state_dict(self) -> dict[str, Any]:
        return {"iteration": self.iteration, **{name: b.state_dict() for name, b in self.sources}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        missing = [name for name in self.tasks if name not in state]
        if missing:
            raise ValueError(
                f"sampler state lacks {missing}; it was saved with tasks {sorted(set(state) - {'iteration'})}"
            )
        self.iteration = int(state["iteration"])
        for name, batcher in self.sources:
            batcher.load_state_dict(state[name])
