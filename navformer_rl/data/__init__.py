"""Datasets on disk (D_e, D_ca, D_ssl): schema, sharded writer, loader, samplers, synthetic data.

Names are imported lazily (so collection workers do not pay for importing torchrl). Collection (pybullet,
experts) lives apart from these names: ``collect`` (the process pool, resume, progress),
``collect_settings`` (settings, scales, unit seeds), ``expert_episodes`` (a work unit's expert episodes
-> rows) and ``versions`` (the behaviour versions that identify collected data).
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "CrossTaskReplayBuffer": "navformer_rl.data.cross_task",
    "NavDataset": "navformer_rl.data.dataset",
    "open_dataset": "navformer_rl.data.dataset",
    "DEFAULT_CONTEXT_STEPS": "navformer_rl.data.samplers",
    "EpisodeTable": "navformer_rl.data.samplers",
    "PairBatcher": "navformer_rl.data.samplers",
    "TrajectoryBatcher": "navformer_rl.data.samplers",
    "TrajectorySampler": "navformer_rl.data.samplers",
    "SCHEMA_VERSION": "navformer_rl.data.schema",
    "DatasetKind": "navformer_rl.data.schema",
    "return_to_go": "navformer_rl.data.schema",
    "make_synthetic_dataset": "navformer_rl.data.synthetic",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
