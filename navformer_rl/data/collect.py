"""Collection of D_e, D_ca and D_ssl (paper §V): work units on a backend, resumable, sharded.

What is collected: :mod:`navformer_rl.data.collect_settings` (settings, scales, unit seeds); what one work
unit does: :mod:`navformer_rl.data.expert_episodes`; the folder, its shards and their consolidation:
:mod:`navformer_rl.data.writer`; where the units run: :mod:`navformer_rl.utils.backends`. On the ``local``
backend (default) units run in a ``spawn`` process pool (one pybullet client per process) and each worker
writes its own shard atomically; on ``ray`` each unit is a Ray task that returns its rows
(:func:`unit_rows`) and this process writes the shard (:func:`write_unit`), the same bytes. The finished
dataset is the first ``n`` items of units 0, 1, 2, ..., so it is identical whatever the backend, the number
of workers and however often collection was interrupted and resumed. Its settings record the versions of
the behaviour that made it (:mod:`navformer_rl.data.versions`), and failed expert episodes are counted in
its ``metadata.json``.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from navformer_rl.data.collect_settings import (
    DAGGER_MIXING,
    SEED_DERIVATION,
    CollectionSettings,
    settings_record,
    target_count,
)
from navformer_rl.data.collect_settings import settings_for as settings_for  # re-exported
from navformer_rl.data.expert_episodes import (
    SSL_PLACEMENT,
    collision_avoidance_unit,
    exploration_unit,
    ssl_unit,
)
from navformer_rl.data.schema import DatasetKind
from navformer_rl.data.versions import VERSIONS_KEY, data_versions
from navformer_rl.data.writer import DatasetWriter, folder_lock, write_shard
from navformer_rl.utils.backends import check_backend, cluster_address, open_backend

UnitRows = tuple[Any, torch.Tensor | None, dict[str, int], dict[str, list[int]]]
"""What a work unit collected, as :func:`~navformer_rl.data.writer.write_shard` takes it: ``(rows, targets,
counters, counters_by_item)``; ``rows`` a flat TensorDict in the kind's schema (None when every episode
failed), ``targets`` uint8 ``[n_items, 84, 84, 3]`` (None for D_ssl and for no items)."""


def run_unit(root: str, kind: str, settings: CollectionSettings, unit: int) -> dict[str, int]:
    """Collect work unit ``unit`` and write its shard under ``root`` (runs inside a worker process)."""
    return write_unit(root, kind, unit, unit_rows(kind, settings, unit))


def unit_rows(kind: str, settings: CollectionSettings, unit: int) -> UnitRows:
    """Collect work unit ``unit`` without writing it (a Ray task of :func:`collect`): :data:`UnitRows`."""
    torch.set_num_threads(1)
    kind = DatasetKind.parse(kind)
    by_item: dict[str, list[int]] = {}
    if kind is DatasetKind.SSL:
        rows, counters = ssl_unit(settings, unit, by_item)
        return rows, None, counters, by_item
    make = exploration_unit if kind is DatasetKind.EXPLORATION else collision_avoidance_unit
    rows, targets, counters = make(settings, unit, by_item)
    td = torch.cat(rows) if rows else None
    tgt = torch.from_numpy(np.stack(targets)) if targets else None
    return td, tgt, counters, by_item


def write_unit(root: str | Path, kind: str, unit: int, collected: UnitRows) -> dict[str, int]:
    """Write the shard of work unit ``unit`` from what :func:`unit_rows` collected; returns its ``items``,
    ``rows`` and counters."""
    kind = DatasetKind.parse(kind)
    rows, targets, counters, by_item = collected
    write_shard(root, kind, unit, rows, targets, counters, by_item)
    n_rows = 0 if rows is None else int(rows.shape[0])
    n_items = n_rows if kind is DatasetKind.SSL else (0 if targets is None else int(targets.shape[0]))
    return {"items": n_items, "rows": n_rows, **counters}


def collect(
    kind: DatasetKind | str,
    out: str | Path,
    settings: CollectionSettings,
    workers: int = 1,
    progress: bool = True,
    unit_fn: Callable[[str, str, Any, int], dict[str, int]] = run_unit,
    backend: str = "local",
    ray_address: str | None = None,
) -> Path:
    """Collect (or resume, or just finish) the dataset ``kind`` into ``out``; returns ``out``.

    ``workers`` run work units: on the ``local`` backend, processes (``spawn``, at most 2 per CPU;
    ``workers=1`` runs them in this process) that each run ``unit_fn``; on ``ray``, Ray tasks
    (:class:`~navformer_rl.utils.backends.RayTasks`: ``ray_address``, else ``$RAY_ADDRESS``, names a
    cluster to join, else a local instance with ``num_cpus=workers`` is started and shut down at the end)
    that run :func:`unit_rows`, this process writing each shard. Either way ``2 x workers`` units are in
    flight at most, and an error or Ctrl-C cancels the rest. Rerunning the same call (with either backend)
    after an interruption continues where it stopped and ends with the same bytes. The folder is locked
    meanwhile (:func:`~navformer_rl.data.writer.folder_lock`): a second collection into it raises
    :class:`~navformer_rl.utils.durable.FolderLockedError` instead of deleting the first one's shards in
    progress.
    """
    kind = DatasetKind.parse(kind)
    check_backend(backend)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if backend == "ray" and unit_fn is not run_unit:
        raise ValueError("unit_fn applies to the local backend; Ray tasks run unit_rows")
    most = 2 * (os.cpu_count() or 1)  # pybullet workers are CPU-bound: more than this only adds overhead
    on_this_machine = backend == "local" or cluster_address(ray_address) is None
    if workers > most and on_this_machine:
        warnings.warn(f"workers={workers} > 2 x {os.cpu_count()} CPUs: using {most}", stacklevel=2)
        workers = most
    with folder_lock(out):
        return _collect_locked(kind, out, settings, workers, progress, unit_fn, backend, ray_address)


def _collect_locked(
    kind: DatasetKind,
    out: str | Path,
    settings: CollectionSettings,
    workers: int,
    progress: bool,
    unit_fn: Callable[[str, str, Any, int], dict[str, int]],
    backend: str,
    address: str | None,
) -> Path:
    """The body of :func:`collect`, run while holding the folder lock."""
    versions = data_versions(kind, dagger=True) if getattr(settings, "dagger", None) else data_versions(kind)
    settings_dict = {"kind": kind.value, **settings_record(settings), VERSIONS_KEY: versions}
    target = target_count(kind, settings)
    writer = DatasetWriter(out, kind, settings_dict, target_count=target)
    if writer.is_complete:
        return writer.finalize()
    items: dict[int, int] = {}

    def covered() -> int:
        total, u = 0, 0
        while u in items and total < target:
            total += items[u]
            u += 1
        return total

    unit = 0
    for done in writer.completed_units():  # checked: a damaged shard is a ValueError saying what to do
        items[done] = writer.check_shard(done)["items"]
    bar = _progress_bar(kind, target, progress)
    bar.update(min(covered(), target))
    parent = (os.getpid(),)
    try:
        with open_backend(
            backend, workers, initializer=_exit_with_parent, initargs=parent, address=address
        ) as run:
            while covered() < target:
                # keep 2 units per worker in flight, in unit order, skipping finished ones
                while run.in_flight < run.slots:
                    while unit in items:
                        unit += 1
                    fills_gap = unit < max(items, default=-1)
                    if not fills_gap and _enough_in_flight(items, run.in_flight, target):
                        break
                    if run.remote:  # the task returns the rows, this process writes the shard
                        run.submit(unit, unit_rows, kind.value, settings, unit)
                    else:
                        run.submit(unit, unit_fn, str(out), kind.value, settings, unit)
                    unit += 1
                if run.in_flight:
                    done, result = run.next_done()
                    if run.remote:
                        result = write_unit(out, kind.value, done, result)
                    _record(items, done, result, bar, covered)
    finally:
        bar.close()
    return writer.finalize(extra_metadata=_provenance(kind, settings))


def _provenance(kind: DatasetKind, settings: CollectionSettings) -> dict[str, Any]:
    """What ``metadata.json`` records besides the settings: the base seed and how unit seeds derive from
    it, for D_ssl how robots are fitted to a world, and with DAgger the policy's checkpoint folder and the
    mixing rule."""
    extra: dict[str, Any] = {"seeds": {"base": settings.seed, "derivation": SEED_DERIVATION}}
    if kind is DatasetKind.SSL:
        extra["robot_placement"] = SSL_PLACEMENT
    dagger = getattr(settings, "dagger", None)
    if dagger is not None:
        extra["dagger"] = {"checkpoint": dagger.checkpoint, "mixing": DAGGER_MIXING}
    return extra


def _enough_in_flight(items: dict[int, int], in_flight: int, target: int) -> bool:
    """True when the units finished or running are expected to cover ``target`` items (mean yield, 5 %
    margin); units below the highest finished one are always scheduled (gaps left by an interruption)."""
    if not items:
        return False
    mean = max(sum(items.values()) / len(items), 1e-3)
    return sum(items.values()) + mean * in_flight >= target * 1.05 + mean


def _record(items: dict[int, int], unit: int, result: dict[str, int], bar, covered) -> None:
    items[unit] = int(result["items"])
    bar.n = min(covered(), bar.total)
    bar.set_postfix(units=len(items), rows=result.get("rows", 0), refresh=False)
    bar.refresh()


def _exit_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this worker when the collecting process dies (e.g. SIGKILL), so no orphan
    keeps running; a shard it was writing stays a temp folder that the next run deletes. Ctrl-C (SIGINT,
    sent to the whole process group) is left to the parent, which stops the workers itself: a worker
    interrupted inside the pool's machinery could otherwise hang the parent's shutdown."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _progress_bar(kind: DatasetKind, total: int, enabled: bool):
    from tqdm.auto import tqdm

    unit = "pairs" if kind is DatasetKind.SSL else "traj"
    return tqdm(total=total, desc=f"collect {kind.value}", unit=unit, disable=not enabled, dynamic_ncols=True)


def default_workers() -> int:
    """All cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)))
