"""Dataset collection recipe: ``python recipes/collect/collect.py kind=ca scale=paper out=/abs/data/ca``.

Thin layer over :func:`navformer_rl.data.collect.collect`: build each kind's settings from the config, then
collect (resumable: rerun the same command after an interruption). Prints each dataset's counts.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import OmegaConf

from navformer_rl.data.collect import collect, default_workers, settings_for
from navformer_rl.data.dataset import open_dataset
from navformer_rl.data.schema import DatasetKind


def make_jobs(cfg) -> list[tuple[DatasetKind, Path, object]]:
    """``[(kind, folder, settings)]`` from the config."""
    out = Path(hydra.utils.to_absolute_path(str(cfg.out)))
    overrides = OmegaConf.to_container(cfg.settings, resolve=True) or {}
    for key, value in overrides.items():
        if isinstance(value, list):
            overrides[key] = tuple(value)
    if cfg.kind == "all":
        if overrides:
            raise ValueError("settings overrides apply to one dataset kind, not to kind=all")
        return [(kind, out / kind.value, settings_for(kind, cfg.scale, cfg.seed)) for kind in DatasetKind]
    kind = DatasetKind.parse(cfg.kind)
    return [(kind, out, settings_for(kind, cfg.scale, cfg.seed, **overrides))]


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg) -> None:
    workers = default_workers() if cfg.workers is None else int(cfg.workers)
    for kind, out, settings in make_jobs(cfg):
        path = collect(kind, out, settings, workers=workers, progress=cfg.progress)
        meta = open_dataset(path, kind).metadata
        print(f"{kind.value}: {path}  counts={meta['counts']}")


if __name__ == "__main__":
    main()
