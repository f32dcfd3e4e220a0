"""Sharded, atomic, resumable writing of a dataset folder.

Layout of a dataset folder::

    metadata.json          schema version, kind, settings, seeds, counts, package version (atomic rewrite)
    .collect.lock          only while collecting: flock + pid of the collecting process (see folder_lock)
    shards/unit-000012/    one per deterministic work unit, renamed into place when complete:
        rows/              memmapped TensorDict of the unit's rows (local episode / target ids from 0)
        targets/           memmapped TensorDict {"target_pixels": uint8 [n, 84, 84, 3]} (trajectory kinds)
        stats.json         {"items": n, "rows": r, "counters": {...}, "counters_by_item": {...},
                            "content_hashes": {"algorithm": "sha256", "files": {"rows/step.memmap": ...}}}
    shards/.tmp-unit-*/    a shard being written; one left by a crash is deleted by the next DatasetWriter
    consolidated/          after completion: rows/ (one flat memmap, global ids) and targets/
                           (built in consolidated.tmp/, then renamed); shards/ is deleted afterwards.

The finished dataset is the first ``target_count`` items (trajectories or pairs) of the contiguous run of
completed units 0, 1, 2, ... so it does not depend on the order in which parallel workers finished, nor on
interruptions: rerunning the same command after a crash yields the same bytes.

A unit's folder is renamed into place only after all its files are written and fsynced, so a committed
shard is complete: one whose ``stats.json`` or memmaps cannot be read was damaged afterwards (disk error,
partial copy, manual edit). Reading it raises ``ValueError`` naming the file and the problem, and saying to
delete that unit's folder so that the next run collects it again (same seed, same data). ``stats.json``
records the sha256 of every memmap file of the shard, so damage that keeps the file sizes (a column
overwritten in place) is found too: when a collection resumes and when the shard is consolidated.
``finalize`` records the sha256 of every consolidated memmap file in ``metadata.json`` (checked by
``open_dataset(..., verify=True)``). Temp folders
(``shards/.tmp-*``) and temp files of interrupted ``metadata.json`` rewrites (``.metadata.*.tmp.json``,
see :func:`navformer_rl.utils.durable.atomic_leftovers`) are provably uncommitted and are deleted silently.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.data.integrity import (
    HASHES_KEY,
    check_sorted,
    content_hashes,
    hashes_problem,
    short_repr,
    trajectory_content_problem,
    verify_hashes,
)
from navformer_rl.data.schema import (
    SCHEMA_VERSION,
    TARGET_FIELDS,
    DatasetKind,
    FieldSpec,
    check_rows,
    fields_for,
    key_name,
)
from navformer_rl.data.versions import VERSIONS_KEY
from navformer_rl.utils.checks import check_int, is_count
from navformer_rl.utils.durable import FolderLockedError as FolderLockedError  # re-exported
from navformer_rl.utils.durable import atomic_leftovers, atomic_write_json, fsync_dir, fsync_tree
from navformer_rl.utils.durable import folder_lock as durable_folder_lock

METADATA_FILE = "metadata.json"
SHARDS_DIR = "shards"
CONSOLIDATED_DIR = "consolidated"
STATS_FILE = "stats.json"
LOCK_FILE = ".collect.lock"
_TMP_PREFIX = ".tmp-"
_UNIT_PREFIX = "unit-"


CODE_KEY = "code_sha256"
"""The settings entry that identifies the collecting code by a sha256 of its source files, in datasets
whose settings hold no :data:`~navformer_rl.data.versions.VERSIONS_KEY`."""

_IDENTITY_KEYS = (VERSIONS_KEY, CODE_KEY)
"""Settings entries that identify the code that made the data rather than the data asked for."""


def _code_identity(settings: dict[str, Any]) -> str:
    """The code identity of stored ``settings`` in words."""
    if CODE_KEY in settings and VERSIONS_KEY not in settings:
        return f"{CODE_KEY} {str(settings[CODE_KEY])[:12]}, a hash of its source files"
    return "no record of its code" if VERSIONS_KEY not in settings else "data versions"


def code_change(old: dict[str, Any], header: dict[str, Any]) -> str | None:
    """How the code identity (:data:`_IDENTITY_KEYS`) of a stored dataset header ``old`` differs from a new
    ``header`` when nothing else of the two differs: the versions that changed (``"data versions
    exploration_expert 1 -> 2"``), or what identifies each code (``"code_sha256 0123456789ab, a hash of
    its source files; now data versions"``). ``None`` when the two are equal or differ elsewhere (other
    settings, kind, schema, size)."""
    was, now = old.get("settings"), header["settings"]
    if not isinstance(was, dict):
        return None
    same_code = all(was.get(key) == now.get(key) for key in _IDENTITY_KEYS)
    rest_was = {k: v for k, v in was.items() if k not in _IDENTITY_KEYS}
    rest_now = {k: v for k, v in now.items() if k not in _IDENTITY_KEYS}
    same_rest = all(old.get(key) == header[key] for key in ("schema_version", "kind", "target_count"))
    if same_code or rest_was != rest_now or not same_rest:
        return None
    versions_was, versions_now = was.get(VERSIONS_KEY), now.get(VERSIONS_KEY)
    if isinstance(versions_was, dict) and isinstance(versions_now, dict) and CODE_KEY not in was:
        names = sorted(
            k for k in {*versions_was, *versions_now} if versions_was.get(k) != versions_now.get(k)
        )
        return "data versions " + ", ".join(
            f"{k} {versions_was.get(k, '(none)')} -> {versions_now.get(k, '(none)')}" for k in names
        )
    return f"{_code_identity(was)}; now {_code_identity(now)}"


def folder_lock(root: str | Path) -> contextlib.AbstractContextManager[Path]:
    """Hold ``root/.collect.lock`` while collecting into ``root``
    (:func:`navformer_rl.utils.durable.folder_lock`: a second live collection gets
    :class:`~navformer_rl.utils.durable.FolderLockedError` naming the holder's pid; a killed one's lock is
    taken over with a warning)."""
    return durable_folder_lock(root, LOCK_FILE, "collected")


_JSON_TYPES = {list: "an array", str: "a string", int: "a number", float: "a number", bool: "a boolean"}


def read_json_object(path: str | Path, remedy: str) -> dict[str, Any]:
    """Parse ``path`` as a JSON object.

    Raises ``ValueError`` naming ``path`` and what is wrong (missing, unreadable, empty, not UTF-8, not
    valid JSON, or JSON that is not an object), followed by ``remedy`` (what the user should do).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ValueError(f"{path} is missing; {remedy}") from None
    except OSError as err:
        raise ValueError(f"{path} cannot be read ({err.strerror or err}); {remedy}") from None
    if not data.strip():
        raise ValueError(f"{path} is empty, expected a JSON object; {remedy}")
    try:
        value = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{path} is not valid JSON (not UTF-8 text: {err.reason} at byte {err.start}); {remedy}"
        ) from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON (truncated or corrupt: {err}); {remedy}") from None
    if not isinstance(value, dict):
        what = _JSON_TYPES.get(type(value), "null")
        raise ValueError(f"{path} holds {what} ({short_repr(value)}), expected a JSON object; {remedy}")
    return value


def shard_dir(root: Path, unit: int) -> Path:
    return Path(root) / SHARDS_DIR / f"{_UNIT_PREFIX}{unit:06d}"


def damaged_shard_remedy(root: str | Path, unit: int) -> str:
    """What to tell the user about a committed shard of ``root`` whose files cannot be read."""
    folder = shard_dir(root, unit)
    return (
        f"work unit {unit} was complete when its folder was renamed into place, so it was damaged afterwards "
        f"(disk error, partial copy, manual edit): delete {folder} and run the same collection again to "
        "collect that unit anew (same seed, same data)"
    )


def memmap_names(part: str, fields: dict[tuple[str, ...], FieldSpec]) -> list[str]:
    """Paths, relative to the folder holding ``part``, of the memmap files of ``fields`` in memmap folder
    ``part``: ``memmap_names("rows", {("next", "reward"): ...}) == ["rows/next/reward.memmap"]``."""
    return [Path(part, *key[:-1], f"{key[-1]}.memmap").as_posix() for key in fields]


def shard_file_names(kind: DatasetKind, n_rows: int) -> list[str]:
    """The memmap files of a shard of ``n_rows`` rows, relative to its unit folder (none when empty)."""
    if not n_rows:
        return []
    names = memmap_names("rows", fields_for(kind))
    return names + (memmap_names("targets", TARGET_FIELDS) if kind.is_trajectory else [])


def consolidated_file_names(kind: DatasetKind) -> list[str]:
    """The memmap files of a finished dataset of ``kind``, relative to the dataset folder."""
    names = memmap_names(f"{CONSOLIDATED_DIR}/rows", fields_for(kind))
    return names + (memmap_names(f"{CONSOLIDATED_DIR}/targets", TARGET_FIELDS) if kind.is_trajectory else [])


def _counters_problem(stats: dict[str, Any]) -> str | None:
    """What is wrong with the ``counters`` / ``counters_by_item`` of a shard's stats (``None`` when nothing);
    ``items`` must already be checked."""
    counters = stats.get("counters")
    if not isinstance(counters, dict):
        return f"'counters' is {short_repr(counters)}, expected an object of non-negative integer counters"
    bad = {name: value for name, value in counters.items() if not is_count(value)}
    if bad:
        return f"counters {short_repr(bad)} are not non-negative integers"
    by_item = stats.get("counters_by_item")
    if not isinstance(by_item, dict):
        return (
            f"'counters_by_item' is {short_repr(by_item)}, expected an object {{counter: [its value through "
            "item 0, through item 1, ...]}}"
        )
    items = stats["items"]
    for name, prefix in by_item.items():
        if name not in counters:
            return f"'counters_by_item' holds {name!r}, which 'counters' lacks"
        valid = isinstance(prefix, list) and len(prefix) == items and all(is_count(v) for v in prefix)
        valid = valid and all(a <= b for a, b in zip(prefix, prefix[1:]))
        if not valid or (prefix and prefix[-1] > counters[name]):
            return (
                f"counters_by_item[{name!r}] is {short_repr(prefix)}, expected {items} non-decreasing "
                f"non-negative integers up to counters[{name!r}] = {counters[name]}"
            )
    return None


def stats_problem(stats: dict[str, Any], kind: DatasetKind) -> str | None:
    """What is wrong with a shard's parsed ``stats.json`` (``None`` when nothing): it must be
    ``{"items": n, "rows": r, "counters": {name: count}, "counters_by_item": {name: [count through item
    0, ..., through item n-1]}, "content_hashes": {"algorithm": "sha256", "files": {path: hex}}}`` with
    non-negative integers, ``n <= r`` for trajectory kinds (a trajectory has at least one row), ``n == r``
    for D_ssl (one row per pair), and a hash of every memmap file of the shard."""
    for key in ("items", "rows"):
        if key not in stats:
            return f"{key!r} is missing, expected {{'items': n, 'rows': r, 'counters': {{...}}}}"
        if not is_count(stats[key]):
            return f"{key!r} is {short_repr(stats[key])}, expected a non-negative integer"
    problem = _counters_problem(stats)
    if problem is not None:
        return problem
    items, rows = stats["items"], stats["rows"]
    if kind.is_trajectory and items > rows:
        return f"'items' is {items} but 'rows' {rows}; every trajectory has at least one row"
    if not kind.is_trajectory and items != rows:
        return f"'items' is {items} but 'rows' {rows}; a D_ssl shard has one row per pair"
    if HASHES_KEY not in stats:
        return (
            f"{HASHES_KEY!r} is missing: the shard was written by a navformer_rl version that recorded no "
            "content hashes, or the file was edited"
        )
    problem = hashes_problem(stats[HASHES_KEY], shard_file_names(kind, rows))
    return None if problem is None else f"{HASHES_KEY!r} {problem}"


def taken_counters(stats: dict[str, Any], take: int) -> dict[str, int]:
    """The counters of a checked shard's first ``take`` items: all of ``counters`` when every item is taken;
    otherwise each counter's value through item ``take - 1`` from ``counters_by_item``, and the whole unit's
    value for a counter that has none (a per-unit count such as ``episodes``)."""
    counters, by_item = stats["counters"], stats["counters_by_item"]
    if take >= stats["items"]:
        return dict(counters)
    taken = {}
    for name, value in counters.items():
        prefix = by_item.get(name)
        taken[name] = value if prefix is None else (prefix[take - 1] if take else 0)
    return taken


def write_shard(
    root: str | Path,
    kind: DatasetKind | str,
    unit: int,
    rows: TensorDict | None,
    targets: torch.Tensor | None,
    counters: dict[str, int],
    counters_by_item: dict[str, list[int]] | None = None,
) -> None:
    """Atomically write work unit ``unit`` (safe to call from worker processes).

    ``rows``: flat TensorDict in the kind's schema with local ``episode``/``target_id`` starting at 0
    (``None`` when the unit produced nothing, e.g. every episode failed), sorted by ``(episode, step)``
    and passing :func:`trajectory_content_problem` for trajectory kinds. ``targets``: uint8
    ``[n_items, 84, 84, 3]`` for trajectory kinds. ``counters``: integer statistics of the whole unit,
    summed into the metadata. ``counters_by_item``: for some of them, the value through each item
    (``n_items`` non-decreasing integers), which the metadata takes when the dataset ends after item ``k``
    of this unit (others count whole). ``stats.json`` also records the sha256 of every memmap file.
    The shard is built in ``shards/.tmp-unit-XXXXXX-<pid>`` and renamed; a crash leaves no partial shard.
    """
    kind = DatasetKind.parse(kind)
    final = shard_dir(root, unit)
    if final.exists():
        return
    where = f"shard {unit} of {root}"
    n_rows, n_items = _check_shard(kind, where, rows, targets)
    stats: dict[str, Any] = {
        "items": n_items,
        "rows": n_rows,
        "counters": {k: int(v) for k, v in counters.items()},
        "counters_by_item": {k: [int(x) for x in v] for k, v in (counters_by_item or {}).items()},
    }
    problem = _counters_problem(stats)
    if problem is not None:
        raise ValueError(f"{where}: {problem}")
    tmp = final.with_name(f"{_TMP_PREFIX}{final.name}-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    if n_rows:
        rows.memmap_(tmp / "rows")
        if kind.is_trajectory:
            TensorDict({"target_pixels": targets.contiguous()}, batch_size=[n_items]).memmap_(tmp / "targets")
    stats[HASHES_KEY] = content_hashes(tmp, shard_file_names(kind, n_rows))
    atomic_write_json(tmp / STATS_FILE, stats)
    fsync_tree(tmp)
    try:
        os.rename(tmp, final)
    except OSError:
        # Another worker finished the same unit first; the two are identical by construction.
        shutil.rmtree(tmp, ignore_errors=True)
        if not final.exists():
            raise
    fsync_dir(final.parent)


def _check_shard(
    kind: DatasetKind, where: str, rows: TensorDict | None, targets: torch.Tensor | None
) -> tuple[int, int]:
    """``(n_rows, n_items)`` of a shard after checking its rows (schema, and for trajectory kinds episodes
    ``0..n_items-1`` matching the targets, sorted by ``(episode, step)``, and their content:
    :func:`trajectory_content_problem`); ``ValueError`` naming ``where``."""
    n_rows = 0 if rows is None else int(rows.shape[0])
    if n_rows:
        check_rows(rows, fields_for(kind), where)
    if not kind.is_trajectory:
        return n_rows, n_rows
    n_items = 0 if targets is None else int(targets.shape[0])
    if not n_rows:
        if n_items:
            raise ValueError(f"{where}: {n_items} targets but no rows")
        return 0, 0
    episodes = rows["episode"]
    if int(episodes.max()) + 1 != n_items or int(episodes.min()) != 0:
        raise ValueError(
            f"{where}: episodes must be numbered 0..{n_items - 1} to match {n_items} targets, "
            f"got {int(episodes.min())}..{int(episodes.max())}"
        )
    check_sorted(episodes, rows["step"], where)
    problem = trajectory_content_problem(rows, kind)
    if problem is not None:
        raise ValueError(f"{where}: key {key_name(problem[0])!r}: {problem[1]}")
    return n_rows, n_items


class DatasetWriter:
    """Owns a dataset folder: metadata, completed-unit bookkeeping and consolidation.

    Args:
        root: dataset folder (created if missing).
        kind: ``"e"``, ``"ca"`` or ``"ssl"``.
        settings: everything that determines the content (sizes, seeds, expert parameters); JSON-able.
            Reopening a folder with different settings raises ``ValueError`` (refusing to mix datasets).
        target_count: number of items of the finished dataset (trajectories, or pairs for ``ssl``).
    """

    def __init__(
        self, root: str | Path, kind: DatasetKind | str, settings: dict[str, Any], target_count: int
    ):
        from navformer_rl import __version__

        self.target_count = check_int(target_count, "target_count")
        self.root = Path(root)
        self.kind = DatasetKind.parse(kind)
        header = {
            "schema_version": SCHEMA_VERSION,
            "kind": self.kind.value,
            "settings": json.loads(json.dumps(settings, sort_keys=True)),
            "target_count": self.target_count,
            "package_version": __version__,
        }
        meta_path = self.root / METADATA_FILE
        # temp files of metadata rewrites interrupted before their rename were never committed (two
        # naming patterns: atomic_write_json's and the plain ``.tmp-metadata.json.*``)
        for leftover in (*atomic_leftovers(meta_path), *self.root.glob(f"{_TMP_PREFIX}{METADATA_FILE}.*")):
            leftover.unlink(missing_ok=True)
        if meta_path.exists():
            old = read_json_object(
                meta_path,
                f"{METADATA_FILE} is only ever replaced atomically, so it was damaged after it was written: "
                f"restore it from a backup, or delete {self.root} and collect again",
            )
            change = code_change(old, header)
            if change is not None:
                if old.get("status") != "complete":
                    raise ValueError(
                        f"{self.root} is an unfinished collection started by other code ({change}): finish "
                        "it with the code version that started it, or delete the folder to collect anew"
                    )
                warnings.warn(
                    f"{self.root} was collected by other code ({change}); it is complete, so it is used as "
                    "it is (delete it to collect with the current code)",
                    UserWarning,
                    stacklevel=2,
                )
                header["settings"] = old["settings"]
            for key in ("schema_version", "kind", "settings", "target_count"):
                if old.get(key) != header[key]:
                    was, now = old.get(key), header[key]
                    if key == "settings" and isinstance(was, dict):
                        names = sorted(k for k in set(was) | set(now) if was.get(k) != now.get(k))
                        was = {k: was.get(k) for k in names}
                        now = {k: now.get(k) for k in names}
                    raise ValueError(
                        f"{self.root} already holds a dataset with {key} {was!r}, but this run asks for "
                        f"{now!r}; use another output folder or delete that one"
                    )
            self.metadata = old
        else:
            self.root.mkdir(parents=True, exist_ok=True)
            self.metadata = {**header, "status": "collecting"}
            atomic_write_json(meta_path, self.metadata)
        (self.root / SHARDS_DIR).mkdir(exist_ok=True)
        for leftover in (self.root / SHARDS_DIR).glob(f"{_TMP_PREFIX}*"):
            shutil.rmtree(leftover, ignore_errors=True)

    @property
    def is_complete(self) -> bool:
        return self.metadata.get("status") == "complete"

    def has_shard(self, unit: int) -> bool:
        return shard_dir(self.root, unit).is_dir()

    def completed_units(self) -> list[int]:
        """Sorted ids of the committed units (the ``shards/unit-NNNNNN/`` folders; temp folders are not).

        Raises ``ValueError`` naming any other ``unit-*`` entry of ``shards/`` (e.g. a copy ``unit-000003
        (2)`` or a file), which would otherwise be mistaken for a unit, or deleted with ``shards/`` after
        consolidation.
        """
        shards = self.root / SHARDS_DIR
        units = []
        for path in sorted(shards.glob(f"{_UNIT_PREFIX}*")):
            digits = path.name[len(_UNIT_PREFIX) :]
            unit = int(digits) if digits.isascii() and digits.isdigit() else None
            if unit is None or path.name != shard_dir(self.root, unit).name or not path.is_dir():
                raise ValueError(
                    f"{path} is not a work-unit folder (expected folders named {_UNIT_PREFIX}NNNNNN, e.g. "
                    f"{shard_dir(self.root, 0).name}, written by the collection); move it out of {shards}, "
                    "which is deleted once the dataset is consolidated"
                )
            units.append(unit)
        return sorted(units)

    def shard_stats(self, unit: int) -> dict[str, Any]:
        """The checked ``stats.json`` of committed unit ``unit``: ``{"items", "rows", "counters"}``.

        Raises ``ValueError`` naming the file, what is wrong with it and how to recover (delete the unit's
        folder to have it collected again): a committed shard's files are complete, so an unreadable one
        was damaged after it was written.
        """
        path = shard_dir(self.root, unit) / STATS_FILE
        stats = read_json_object(path, damaged_shard_remedy(self.root, unit))
        problem = stats_problem(stats, self.kind)
        if problem is not None:
            raise ValueError(f"{path}: {problem}; {damaged_shard_remedy(self.root, unit)}")
        return stats

    def check_shard(self, unit: int) -> dict[str, Any]:
        """:meth:`shard_stats` of committed unit ``unit`` after also checking that each of its memmap files
        exists with the byte size its ``stats.json`` implies and still has the sha256 recorded there (each
        file is read once: about 1.2 s per GB here). Run on every unit when a collection resumes, so a
        damaged shard is reported before any work, and on every unit consolidated. Raises ``ValueError``
        naming the file and saying to delete the unit's folder.
        """
        stats = self.shard_stats(unit)
        folder = shard_dir(self.root, unit)
        try:
            if stats["rows"]:
                check_memmap_files(folder / "rows", fields_for(self.kind), stats["rows"])
                if self.kind.is_trajectory:
                    check_memmap_files(folder / "targets", TARGET_FIELDS, stats["items"])
            verify_hashes(folder, stats[HASHES_KEY], folder / STATS_FILE)
        except (ValueError, FileNotFoundError) as err:
            raise ValueError(f"{err}; {damaged_shard_remedy(self.root, unit)}") from None
        return stats

    def _load_shard(
        self, unit: int, part: str, fields: dict[tuple[str, ...], FieldSpec], n: int
    ) -> TensorDict:
        """Memmap folder ``part`` (``rows`` / ``targets``) of committed unit ``unit``, checked like
        :func:`load_checked`; any problem is a ``ValueError`` that says how to recover."""
        try:
            return load_checked(shard_dir(self.root, unit) / part, fields, n)
        except (ValueError, FileNotFoundError) as err:
            raise ValueError(f"{err}; {damaged_shard_remedy(self.root, unit)}") from None

    def write_shard(
        self,
        unit: int,
        rows: TensorDict | None,
        targets: torch.Tensor | None,
        counters: dict[str, int],
        counters_by_item: dict[str, list[int]] | None = None,
    ) -> None:
        """:func:`write_shard` into this dataset's folder."""
        write_shard(self.root, self.kind, unit, rows, targets, counters, counters_by_item)

    def prefix_plan(self) -> tuple[list[tuple[int, int]], int]:
        """Units 0, 1, ... while complete: ``([(unit, items_taken)], items_total)``, stopping once
        ``target_count`` items are covered."""
        plan: list[tuple[int, int]] = []
        total = 0
        unit = 0
        while total < self.target_count and self.has_shard(unit):
            items = self.shard_stats(unit)["items"]
            take = min(items, self.target_count - total)
            plan.append((unit, take))
            total += take
            unit += 1
        return plan, total

    def needs_more(self) -> bool:
        """Whether the completed prefix of units still lacks items."""
        return not self.is_complete and self.prefix_plan()[1] < self.target_count

    def finalize(self, extra_metadata: dict[str, Any] | None = None) -> Path:
        """Consolidate the completed prefix into ``consolidated/`` and mark the dataset complete.

        Every shard used is checked first (:meth:`check_shard`: sizes and content hashes). The metadata's
        ``counts`` sum the shards' counters over the items taken (:func:`taken_counters`: the last unit
        used may give only its first items), and ``content_hashes`` records the sha256 of every
        consolidated memmap file. Idempotent: rerunning after a crash at any point gives the same folder.
        Returns ``root``.
        """
        if self.is_complete:
            self._remove_shards()
            return self.root
        plan, total = self.prefix_plan()
        if total < self.target_count:
            raise RuntimeError(
                f"{self.root}: only {total} of {self.target_count} items are collected; run collection first"
            )
        fields = fields_for(self.kind)
        n_rows = 0
        row_counts = []
        counters: dict[str, int] = {}
        for unit, take in plan:
            stats = self.check_shard(unit)  # a shard changed since it was written is refused here
            for key, value in taken_counters(stats, take).items():
                counters[key] = counters.get(key, 0) + value
            rows = self._take_rows(unit, take)
            row_counts.append(rows)
            n_rows += rows
        tmp = self.root / f"{CONSOLIDATED_DIR}.tmp"
        final = self.root / CONSOLIDATED_DIR
        for stale in (tmp, final):
            if stale.exists():
                shutil.rmtree(stale)
        out = _preallocate(tmp / "rows", fields, n_rows)
        targets_out = (
            _preallocate(tmp / "targets", TARGET_FIELDS, self.target_count)["target_pixels"]
            if self.kind.is_trajectory
            else None
        )
        row_at, item_at = 0, 0
        for (unit, take), rows in zip(plan, row_counts):
            if rows == 0:
                continue
            stats = self.shard_stats(unit)
            shard = self._load_shard(unit, "rows", fields, stats["rows"])
            for key in fields:
                out.get(key)[row_at : row_at + rows].copy_(shard.get(key)[:rows])
            if self.kind.is_trajectory:
                out["episode"][row_at : row_at + rows] += item_at
                out["target_id"][row_at : row_at + rows] += item_at
                shard_targets = self._load_shard(unit, "targets", TARGET_FIELDS, stats["items"])
                targets_out[item_at : item_at + take].copy_(shard_targets["target_pixels"][:take])
            row_at += rows
            item_at += take
        fsync_tree(tmp)
        os.rename(tmp, final)
        fsync_dir(self.root)
        counts = {"rows": n_rows, "items": self.target_count, "units": len(plan), **counters}
        self.metadata = {
            **self.metadata,
            **(extra_metadata or {}),
            "status": "complete",
            "counts": counts,
            "statistics": dataset_statistics(TensorDict.load_memmap(final / "rows"), self.kind),
            HASHES_KEY: content_hashes(self.root, consolidated_file_names(self.kind)),
        }
        atomic_write_json(self.root / METADATA_FILE, self.metadata)
        self._remove_shards()
        return self.root

    def _take_rows(self, unit: int, take_items: int) -> int:
        """Rows of the first ``take_items`` items of a shard (its rows are ordered by local episode)."""
        stats = self.shard_stats(unit)
        if take_items == stats["items"]:
            return stats["rows"]
        if not self.kind.is_trajectory:
            return take_items
        episodes = self._load_shard(unit, "rows", fields_for(self.kind), stats["rows"])["episode"]
        return int((episodes < take_items).sum())

    def _remove_shards(self) -> None:
        shutil.rmtree(self.root / SHARDS_DIR, ignore_errors=True)


def _preallocate(path: Path, fields: dict, n_rows: int) -> TensorDict:
    """Empty memmapped TensorDict ``[n_rows]`` with the given fields, written under ``path``."""
    template = TensorDict(
        {key: torch.zeros((1, *spec.shape), dtype=spec.dtype) for key, spec in fields.items()}, batch_size=[1]
    )
    return template.expand(n_rows).memmap_like(path)


def dataset_statistics(rows: TensorDict, kind: DatasetKind) -> dict[str, Any]:
    """Summary numbers of a consolidated dataset for the metadata and the dataset card."""
    if not kind.is_trajectory:
        worlds = rows["world"].numpy()
        return {"pairs": int(rows.shape[0]), "worlds": int(np.unique(worlds).size)}
    episode = rows["episode"].numpy()
    lengths = np.bincount(episode)
    collision = rows["next", "collision"].numpy()[:, 0]
    per_traj_collisions = np.bincount(episode, weights=collision.astype(np.float64), minlength=lengths.size)
    success = rows["next", "terminated"].numpy()[:, 0]
    return {
        "trajectories": int(lengths.size),
        "steps": int(episode.size),
        "length_min": int(lengths.min()),
        "length_mean": float(round(lengths.mean(), 3)),
        "length_median": float(np.median(lengths)),
        "length_max": int(lengths.max()),
        "successful_trajectories": int(success.sum()),
        "collision_steps": int(collision.sum()),
        "collision_rate_per_step": float(round(collision.mean(), 6)),
        "trajectories_with_collision": int((per_traj_collisions > 0).sum()),
    }


def check_memmap_files(folder: Path, fields: dict[tuple[str, ...], FieldSpec], n_rows: int) -> None:
    """Check that memmap folder ``folder`` holds, for every key of ``fields``, a file of the byte size of
    ``n_rows`` rows (``stat`` only). Raises ``FileNotFoundError`` naming a missing folder or file,
    ``ValueError`` naming a path that is not a folder / file or a file of the wrong size."""
    if not folder.is_dir():
        if folder.exists():
            raise ValueError(f"{folder} is not a folder (expected a memmapped TensorDict folder)")
        raise FileNotFoundError(f"{folder} is missing (expected a memmapped TensorDict folder)")
    for key, spec in fields.items():
        file = folder.joinpath(*key[:-1], f"{key[-1]}.memmap")
        if not file.is_file():
            if file.exists():
                raise ValueError(f"{file} is not a file (expected the memmap of key {key_name(key)!r})")
            raise FileNotFoundError(f"{file} is missing (key {key_name(key)!r})")
        expected = spec.nbytes(n_rows)
        actual = file.stat().st_size
        if actual != expected:
            raise ValueError(
                f"{file} has {actual} bytes, expected {expected} ({n_rows} rows of {spec.dtype} "
                f"{spec.shape}); the file is truncated or does not belong to this dataset"
            )


def load_checked(folder: Path, fields: dict[tuple[str, ...], FieldSpec], n_rows: int) -> TensorDict:
    """Load a memmapped TensorDict after checking every file's existence, size, dtype and shape.

    Raises ``FileNotFoundError`` naming a missing folder or memmap file, ``ValueError`` naming the file or
    folder for anything else (a path that is not a folder / file, a wrong byte size for ``n_rows`` rows, an
    unreadable ``meta.json``, a key it does not list, a wrong dtype or shape).
    """
    check_memmap_files(folder, fields, n_rows)
    try:
        td = TensorDict.load_memmap(folder)
    except Exception as err:  # tensordict raises assorted errors for a corrupt meta.json
        raise ValueError(
            f"{folder}: cannot read the memmapped TensorDict ({type(err).__name__}: {err})"
        ) from None
    for key, spec in fields.items():
        value = td.get(key, None)
        if not isinstance(value, torch.Tensor):
            raise ValueError(
                f"{folder / 'meta.json'} does not describe key {key_name(key)!r} as a tensor "
                f"(expected {spec.dtype} {(n_rows, *spec.shape)}); the folder is damaged"
            )
        if value.dtype != spec.dtype or tuple(value.shape) != (n_rows, *spec.shape):
            raise ValueError(
                f"{folder}: key {key_name(key)!r} is {value.dtype} {tuple(value.shape)}, "
                f"expected {spec.dtype} {(n_rows, *spec.shape)}"
            )
    return td
