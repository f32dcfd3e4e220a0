"""The demo's settings (:class:`DemoConfig`, two shipped presets) and the small helpers its stages and report
share (machine facts, JSON writes)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from navformer_rl.utils.durable import atomic_write_text

BASELINES = ("vrw", "fca")
HELD_OUT_SEED_OFFSET = 1000
"""The held-out D_e / D_ca are collected with ``seed + HELD_OUT_SEED_OFFSET``:
mazes the training never saw."""
TRAINED_METHODS = ("navformer", "dt")
STAGE_TIMES_FILENAME = "stage_times.json"
"""File of the run folder keeping the seconds that computed each stage's result (:class:`StageTimes`)."""


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the small end-to-end run (the paper-scale values are in ``docs/reproduce.md``).

    Attributes:
        out_dir: run folder.
        seed: base seed of collection, training and evaluation.
        workers: processes for collection and evaluation.
        exploration_trajectories, collision_trajectories: D_e / D_ca trajectories (paper: 3,496 / 7,467).
        ssl_worlds, ssl_pairs_per_world: D_ssl size (paper: 1,000 x 98).
        held_out_exploration, held_out_collision: held-out D_e / D_ca trajectories for validation (0: none).
        iterations: training iterations of NavFormer and of DT (paper: 10,000).
        exploration_batch, collision_batch, ssl_batch: trajectories / pairs per iteration (paper: 25/150/512).
        setups: evaluation protocol (a name of ``navformer_rl.evaluation.episodes.PROTOCOLS``).
        trials_per_setup, trials_per_world: evaluation trials (paper: 60 per setup, new world every 10).
        max_steps: steps per evaluation trial (paper: 500).
        videos_per_setup: episodes recorded as mp4 per setup and method.
        shipped: shipped weights (``pretrained:NAME``) evaluated on the same episodes beside the methods
            trained here, when this installation ships them (``navformer pretrained list``); others are
            skipped.
    """

    out_dir: Path = Path("runs/demo")
    seed: int = 0
    workers: int = 2
    exploration_trajectories: int = 48
    collision_trajectories: int = 96
    ssl_worlds: int = 8
    ssl_pairs_per_world: int = 64
    held_out_exploration: int = 16
    held_out_collision: int = 32
    iterations: int = 200
    exploration_batch: int = 8
    collision_batch: int = 24
    ssl_batch: int = 128
    setups: str = "smoke"
    trials_per_setup: int = 6
    trials_per_world: int = 3
    max_steps: int = 500
    videos_per_setup: int = 1
    methods: tuple[str, ...] = field(default=TRAINED_METHODS + BASELINES)
    shipped: tuple[str, ...] = ("navformer",)

    @staticmethod
    def preset(name: str, **overrides) -> DemoConfig:
        """``default`` (8-15 minutes on 2 CPU cores, README.md) or ``quick`` (a few minutes:
        a smoke check)."""
        presets = {
            "default": {},
            "quick": {
                "exploration_trajectories": 6,
                "collision_trajectories": 12,
                "ssl_worlds": 2,
                "ssl_pairs_per_world": 32,
                "held_out_exploration": 2,
                "held_out_collision": 4,
                "iterations": 20,
                "exploration_batch": 4,
                "collision_batch": 8,
                "ssl_batch": 32,
                "trials_per_setup": 2,
                "trials_per_world": 2,
                "max_steps": 120,
            },
        }
        if name not in presets:
            raise ValueError(f"unknown demo preset {name!r}; expected one of {sorted(presets)}")
        return dataclasses.replace(DemoConfig(), **{**presets[name], **overrides})

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        positive = (
            "workers exploration_trajectories collision_trajectories ssl_worlds ssl_pairs_per_world "
            "iterations exploration_batch collision_batch ssl_batch trials_per_setup trials_per_world "
            "max_steps"
        ).split()
        for name in positive:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"demo setting {name}={value!r}: expected a positive integer")
        for name in ("held_out_exploration", "held_out_collision"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"demo setting {name}={value!r}: expected an integer >= 0 (0: none)")
        unknown = sorted(set(self.methods) - set(TRAINED_METHODS + BASELINES))
        if unknown or not self.methods:
            raise ValueError(
                f"demo methods {list(self.methods)!r}: expected a non-empty subset of "
                f"{list(TRAINED_METHODS + BASELINES)}"
            )
        from navformer_rl.training.pretrained_registry import check_name

        for name in self.shipped:
            check_name(name)
        if self.exploration_batch > self.exploration_trajectories:
            raise ValueError(
                f"exploration_batch={self.exploration_batch} exceeds exploration_trajectories="
                f"{self.exploration_trajectories}"
            )
        if self.collision_batch > self.collision_trajectories:
            raise ValueError(
                f"collision_batch={self.collision_batch} exceeds collision_trajectories="
                f"{self.collision_trajectories}"
            )


def environment_summary() -> dict[str, str]:
    """Machine facts recorded in the report (threads, torch version, device)."""
    import platform

    import torch

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_count": str(os.cpu_count()),
        "cuda": str(torch.cuda.is_available()),
    }


def write_json(path: Path, payload: dict) -> None:
    """Atomically and durably write ``payload`` as JSON."""
    atomic_write_text(path, json.dumps(payload, indent=2, default=str) + "\n")
