"""Dataset collection recipe: ``python recipes/collect/collect.py kind=ca scale=paper out=/abs/data/ca``.

Thin layer over :func:`navformer_rl.data.collect.collect`: build each kind's settings from the config, then
collect (resumable: rerun the same command after an interruption). Prints each dataset's counts.

A mistake the user can fix is printed as one line, ``collect.py: error: <message>``, with exit status 2, like
``navformer collect`` (``NAVFORMER_DEBUG=1`` shows the traceback); a refused run leaves no hydra folder
behind.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import OmegaConf

from navformer_rl.data.collect import collect, default_workers, settings_for
from navformer_rl.data.dataset import open_dataset
from navformer_rl.data.schema import DatasetKind
from navformer_rl.utils.backends import session

# recipes/ holds recipe_errors.py, which the recipes share
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from recipe_errors import user_errors  # noqa: E402


def make_jobs(cfg) -> list[tuple[DatasetKind, Path, object]]:
    """``[(kind, folder, settings)]`` from the config."""
    out = Path(hydra.utils.to_absolute_path(str(cfg.out)))
    overrides = OmegaConf.to_container(cfg.settings, resolve=True) or {}
    for key, value in overrides.items():
        if isinstance(value, list):
            overrides[key] = tuple(value)
    if cfg.get("dagger_policy") is not None and cfg.kind == "ssl":
        raise ValueError("dagger_policy applies to e and ca (D_ssl has no actions)")
    if "dagger" in overrides:
        raise ValueError("set dagger_policy= (and dagger_beta=), not settings.dagger")
    dagger = {} if cfg.get("dagger_policy") is None else {"dagger": _dagger(cfg)}
    if cfg.kind == "all":
        if overrides:
            raise ValueError("settings overrides apply to one dataset kind, not to kind=all")
        return [
            (
                kind,
                out / kind.value,
                settings_for(kind, cfg.scale, cfg.seed, **({} if kind is DatasetKind.SSL else dagger)),
            )
            for kind in DatasetKind
        ]
    kind = DatasetKind.parse(cfg.kind)
    return [(kind, out, settings_for(kind, cfg.scale, cfg.seed, **dagger, **overrides))]


def _dagger(cfg):
    """The DAgger settings of ``dagger_policy`` / ``dagger_beta`` (a relative path from the launch folder)."""
    from navformer_rl.data.dagger import dagger_settings

    policy = str(cfg.dagger_policy)
    if not policy.startswith("pretrained:"):
        policy = hydra.utils.to_absolute_path(policy)
    return dagger_settings(policy, float(cfg.dagger_beta))


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg) -> None:
    # A mistake (unknown kind or scale, bad worker count, a foreign folder as `out`, ...) ends in one line
    # and exit status 2 (NAVFORMER_DEBUG=1: the traceback)
    with user_errors("collect.py"):
        workers = default_workers() if cfg.workers is None else int(cfg.workers)
        backend, address = str(cfg.backend), cfg.ray_address
        jobs = make_jobs(cfg)
        with session(backend, workers, address):  # one Ray session for every kind of kind=all
            for kind, out, settings in jobs:
                path = collect(
                    kind,
                    out,
                    settings,
                    workers=workers,
                    progress=cfg.progress,
                    backend=backend,
                    ray_address=address,
                )
                meta = open_dataset(path, kind).metadata
                print(f"{kind.value}: {path}  counts={meta['counts']}")


if __name__ == "__main__":
    main()
