"""The data versions are honest: a tiny seeded collection of each kind has its signature recorded next to
them.

A dataset's identity is its settings plus the numbers of ``navformer_rl.data.versions.DATA_VERSIONS`` (not
its code's text). These tests collect a tiny dataset of each kind through the real simulator and experts
(1 worker, seconds each) and compare its signature (:func:`data_signature`) with the one recorded in
:data:`SIGNATURE_FILE` with the versions that made it. A change in the data without a version bump fails here.

The signature holds the counts, the trajectory lengths and the integer / bool columns exactly, the float
columns to :data:`FLOAT_ATOL`, and of each image its mean and std (to :data:`MEAN_STD_ATOL`) and a coarse
8 x 8 block-mean thumbnail (to :data:`THUMB_ATOL`): float actions and rendered pixels may differ in their
last bits between CPUs (SIMD dispatch, libm), so a byte hash would fail on another machine although the
behaviour did not change.

Re-record after a version bump with ``.venv/bin/python tests/data/test_data_versions.py --record``.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from navformer_rl.data.collect import collect, settings_for
from navformer_rl.data.dataset import NavDataset, open_dataset
from navformer_rl.data.schema import TARGET_FIELDS, DatasetKind, fields_for, key_name
from navformer_rl.data.versions import KIND_VERSIONS, data_versions

SETTINGS = {
    "e": settings_for("e", "small", seed=1, n_trajectories=1, episodes_per_unit=1, world_sizes=(7.5,)),
    "ca": settings_for("ca", "small", seed=0, n_trajectories=2, other_robots=(2, 2)),
    "ssl": settings_for(
        "ssl", "small", seed=0, n_worlds=1, pairs_per_world=6, robots=(4, 4), world_sizes=(5.0,)
    ),
}
"""Tiny collections: a 123-step exploration of a 7.5 m maze, one arena episode of 3 robots (2 stored),
one 5 m maze with 4 robots in 2 layouts (6 pairs)."""

SIGNATURE_FILE = Path(__file__).with_name("data_versions_signature.json")
"""Per kind: ``{"versions": {name: number}, "signature": data_signature(...)}`` of :data:`SETTINGS`."""

RECORD_COMMAND = ".venv/bin/python tests/data/test_data_versions.py --record"

FLOAT_ATOL = 1e-4
"""Float columns (actions, rewards, return-to-go, poses, positions); yaw is compared modulo 2 pi."""
MEAN_STD_ATOL = 0.25
"""Per-image mean and std of the uint8 pixels, in intensity levels."""
THUMB_ATOL = 2.0
"""Each value of an image's 8 x 8 x 3 block-mean thumbnail, in intensity levels."""
THUMB_SIZE = 8
MAX_THUMBS = 16
"""Thumbnails per image column at most: of every ``ceil(n / MAX_THUMBS)``-th image (keeps the file small)."""
ANGLE_COLUMN = {"privileged.pose": 2, "pose": 2}
"""Float keys with an angle (yaw) in this column of their last axis."""
MAX_LISTED = 12
"""Differences listed in a failure message at most."""


def thumbnail(image: np.ndarray) -> np.ndarray:
    """uint8 ``[H, W, C]`` -> float64 ``[8, 8, C]``: the means of an 8 x 8 grid of (near-)equal blocks."""
    h, w = image.shape[:2]
    rows = np.linspace(0, h, THUMB_SIZE + 1).round().astype(int)
    cols = np.linspace(0, w, THUMB_SIZE + 1).round().astype(int)
    sums = np.add.reduceat(np.add.reduceat(image.astype(np.float64), rows[:-1], axis=0), cols[:-1], axis=1)
    return sums / (np.diff(rows)[:, None, None] * np.diff(cols)[None, :, None])


def image_signature(images: np.ndarray) -> dict[str, Any]:
    """uint8 ``[N, H, W, C]`` -> per-image ``mean`` / ``std`` ``[N]`` and ``thumb`` ``[K, 8, 8, C]`` of the
    images ``thumb_rows`` ``[K]`` (every ``ceil(N / MAX_THUMBS)``-th), rounded for JSON."""
    pixels = images.reshape(len(images), -1).astype(np.float64)
    thumb_rows = list(range(0, len(images), max(1, math.ceil(len(images) / MAX_THUMBS))))
    return {
        "mean": pixels.mean(axis=1).round(3).tolist(),
        "std": pixels.std(axis=1).round(3).tolist(),
        "thumb_rows": thumb_rows,
        "thumb": [thumbnail(images[i]).round(1).tolist() for i in thumb_rows],
    }


def _table(column: np.ndarray) -> np.ndarray:
    """A column ``[N, ...]`` as ``[N]`` when it holds one value per row, else ``[N, values]``."""
    table = column.reshape(len(column), -1)
    return table[:, 0] if table.shape[1] == 1 else table


def data_signature(dataset: NavDataset) -> dict[str, Any]:
    """The signature of a dataset: every stored key of its schema (and the target images), by dtype.

    ``items`` (trajectories or pairs), ``rows``, ``lengths`` (steps per trajectory; ``[]`` for D_ssl),
    ``exact`` (int / bool columns as ints) and ``close`` (float columns rounded to 1e-6), both ``[rows]`` or
    ``[rows, values]``, and ``images`` (:func:`image_signature` of each uint8 column and of
    ``target_pixels``).
    """
    columns = {key_name(key): dataset.rows.get(key).numpy() for key in fields_for(dataset.kind)}
    if dataset.targets is not None:
        columns[key_name(next(iter(TARGET_FIELDS)))] = dataset.targets.numpy()
    exact, close, images = {}, {}, {}
    for name, value in sorted(columns.items()):
        if value.dtype == np.uint8:
            images[name] = image_signature(value)
        elif value.dtype.kind == "f":
            close[name] = _table(value.astype(np.float64)).round(6).tolist()
        else:
            exact[name] = _table(value.astype(np.int64)).tolist()
    lengths = [] if dataset.episodes is None else np.bincount(columns["episode"]).tolist()
    items = len(lengths) if dataset.kind.is_trajectory else len(dataset)
    return {
        "items": items,
        "rows": len(dataset),
        "lengths": lengths,
        "exact": exact,
        "close": close,
        "images": images,
    }


def _difference(
    name: str, recorded: Any, found: Any, atol: float, angle_column: int | None = None
) -> str | None:
    """A one-line account of where ``found`` differs from ``recorded`` by more than ``atol``, or ``None``."""
    recorded, found = np.asarray(recorded, dtype=np.float64), np.asarray(found, dtype=np.float64)
    if recorded.shape != found.shape:
        return f"{name}: shape {found.shape}, recorded {recorded.shape}"
    diff = np.abs(found - recorded)
    if angle_column is not None and diff.size:
        diff[..., angle_column] = np.abs(
            np.remainder(diff[..., angle_column] + math.pi, 2 * math.pi) - math.pi
        )
    bad = diff > atol
    if not bad.any():
        return None
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    return (
        f"{name}: {int(bad.sum())} value(s) differ by more than {atol:g}, the first at index {first}: "
        f"{found[first]:g}, recorded {recorded[first]:g}"
    )


def _key_sets(where: str, recorded: dict, found: dict) -> list[str]:
    if recorded.keys() == found.keys():
        return []
    return [f"{where} keys {sorted(found)}, recorded {sorted(recorded)}"]


def signature_differences(recorded: dict[str, Any], found: dict[str, Any]) -> list[str]:
    """One line per difference of ``found`` from ``recorded`` (:func:`data_signature`s) beyond tolerance.

    ``items``, ``rows``, ``lengths`` and the ``exact`` columns must be equal; the ``close`` columns agree
    within :data:`FLOAT_ATOL`; each image's ``mean`` / ``std`` within :data:`MEAN_STD_ATOL` and its
    thumbnail within :data:`THUMB_ATOL`. ``[]`` when they agree.
    """
    out = [
        f"{name}: {found[name]}, recorded {recorded[name]}"
        for name in ("items", "rows", "lengths")
        if found[name] != recorded[name]
    ]
    for group, atol in (("exact", 0.0), ("close", FLOAT_ATOL)):
        out += _key_sets(group, recorded[group], found[group])
        for name in sorted(recorded[group].keys() & found[group].keys()):
            out.append(
                _difference(name, recorded[group][name], found[group][name], atol, ANGLE_COLUMN.get(name))
            )
    out += _key_sets("images", recorded["images"], found["images"])
    for name in sorted(recorded["images"].keys() & found["images"].keys()):
        rec, got = recorded["images"][name], found["images"][name]
        out += [
            _difference(f"{name} {stat}", rec[stat], got[stat], MEAN_STD_ATOL) for stat in ("mean", "std")
        ]
        if got["thumb_rows"] != rec["thumb_rows"]:
            out.append(f"{name} thumbnails: of rows {got['thumb_rows']}, recorded {rec['thumb_rows']}")
        else:
            out.append(_difference(f"{name} thumbnails", rec["thumb"], got["thumb"], THUMB_ATOL))
    return [line for line in out if line is not None]


def mismatch_message(
    kind: str, differences: list[str], then: str = f"then re-record with `{RECORD_COMMAND}`"
) -> str:
    """The failure message for ``kind``'s data differing from its recorded signature: the differences, what
    to bump, and ``then`` what to do."""
    listed = "\n".join(f"  - {line}" for line in differences[:MAX_LISTED])
    more = f"\n  ... and {len(differences) - MAX_LISTED} more" if len(differences) > MAX_LISTED else ""
    return (
        f"the collected {kind} data differs from its signature in {SIGNATURE_FILE.name}:\n{listed}{more}\n"
        f"bump {' or '.join(KIND_VERSIONS[DatasetKind.parse(kind)])} (whichever behaviour changed) in "
        "navformer_rl/data/versions.py, or SCHEMA_VERSION in navformer_rl/data/schema.py for a change of "
        f"the stored keys, {then}"
    )


def collect_signature(kind: str, folder: Path) -> dict[str, Any]:
    """Collect :data:`SETTINGS` of ``kind`` into ``folder`` (1 worker) and return its
    :func:`data_signature`."""
    return data_signature(
        open_dataset(collect(kind, folder / kind, SETTINGS[kind], workers=1, progress=False))
    )


def load_recorded() -> dict[str, Any]:
    """The content of :data:`SIGNATURE_FILE` (``{}`` when it does not exist)."""
    return json.loads(SIGNATURE_FILE.read_text()) if SIGNATURE_FILE.is_file() else {}


def _dumps(value: Any, indent: int = 0) -> str:
    """JSON with one line per leaf value (dicts indented, lists on one line), for readable diffs."""
    if not isinstance(value, dict) or not value:
        return json.dumps(value, separators=(",", ":"))
    pad = " " * (indent + 1)
    items = ",\n".join(f"{pad}{json.dumps(k)}: {_dumps(v, indent + 1)}" for k, v in value.items())
    return "{\n" + items + "\n" + " " * indent + "}"


def record(force: bool = False) -> None:
    """Collect every kind and rewrite :data:`SIGNATURE_FILE` with its signature and versions.

    Refuses (``SystemExit``) a kind whose versions equal the recorded ones while its data differs from the
    recorded signature (bump a version first) unless ``force`` (e.g. a signature recorded on a CPU whose
    results differ beyond the tolerances).
    """
    recorded = load_recorded()
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as folder:
        for kind in sorted(SETTINGS):
            signature, versions = collect_signature(kind, Path(folder)), data_versions(kind)
            old = recorded.get(kind)
            differences = signature_differences(old["signature"], signature) if old else ["not recorded"]
            if old and differences and old["versions"] == versions and not force:
                raise SystemExit(
                    mismatch_message(kind, differences, then="then record again (or pass --force)")
                )
            status = "unchanged" if not differences else f"recorded with versions {versions}"
            print(f"{kind}: {status}")
            out[kind] = {"versions": versions, "signature": signature}
    SIGNATURE_FILE.write_text(_dumps(out) + "\n")
    print(f"wrote {SIGNATURE_FILE} ({SIGNATURE_FILE.stat().st_size / 1e3:.0f} kB)")


@pytest.mark.parametrize("kind", sorted(SETTINGS))
def test_the_collected_data_matches_its_recorded_versions(kind, tmp_path):
    recorded = load_recorded()
    assert kind in recorded, (
        f"{SIGNATURE_FILE.name} has no signature of {kind}: record it with `{RECORD_COMMAND}`"
    )
    assert data_versions(kind) == recorded[kind]["versions"], (
        f"the data versions of {kind} are now {data_versions(kind)}, but its signature in "
        f"{SIGNATURE_FILE.name} was recorded with {recorded[kind]['versions']}: "
        f"re-record with `{RECORD_COMMAND}`"
    )
    differences = signature_differences(recorded[kind]["signature"], collect_signature(kind, tmp_path))
    assert not differences, mismatch_message(kind, differences)


def _hand_made_signature() -> dict[str, Any]:
    """A small signature of 2 trajectories (3 and 2 steps) with one float column and one image column."""
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, size=(5, 84, 84, 3), dtype=np.uint8)
    return {
        "items": 2,
        "rows": 5,
        "lengths": [3, 2],
        "exact": {"episode": [0, 0, 0, 1, 1], "next.done": [0, 0, 1, 0, 1]},
        "close": {
            "action": rng.uniform(-1, 1, size=(5, 2)).round(6).tolist(),
            "privileged.pose": [[0.0, 0.0, math.pi - 1e-5]] * 5,
        },
        "images": {"pixels": image_signature(images)},
    }


def test_the_signature_of_an_image_is_its_mean_std_and_block_means():
    image = np.zeros((84, 84, 3), dtype=np.uint8)
    image[:42, :, 0] = 200  # the top half's red channel
    sig = image_signature(image[None])
    assert sig["mean"] == [round(200 * 42 * 84 / (84 * 84 * 3), 3)]
    assert sig["thumb_rows"] == [0]
    thumb = np.array(sig["thumb"][0])
    assert thumb.shape == (8, 8, 3)
    np.testing.assert_array_equal(thumb[:4, :, 0], 200.0)
    np.testing.assert_array_equal(thumb[4:, :, 0], 0.0)
    np.testing.assert_array_equal(thumb[..., 1:], 0.0)
    assert image_signature(np.zeros((40, 84, 84, 3), dtype=np.uint8))["thumb_rows"] == list(range(0, 40, 3))


def test_signatures_within_the_tolerances_agree():
    recorded, found = _hand_made_signature(), _hand_made_signature()
    found["close"]["action"][1][0] += 0.5 * FLOAT_ATOL
    found["close"]["privileged.pose"][2][2] = -math.pi + 1e-5  # the same yaw, across the wrap
    found["images"]["pixels"]["mean"][0] += 0.2
    found["images"]["pixels"]["std"][4] -= 0.2
    found["images"]["pixels"]["thumb"][1][3][5][2] += 1.5
    assert signature_differences(recorded, found) == []


@pytest.mark.parametrize(
    ("perturb", "expected"),
    [
        (
            lambda s: s.update(rows=6, lengths=[4, 2]),
            ["rows: 6, recorded 5", "lengths: [4, 2], recorded [3, 2]"],
        ),
        (
            lambda s: s["exact"]["next.done"].__setitem__(2, 0),
            ["next.done: 1 value(s) differ by more than 0, the first at index (2,): 0, recorded 1"],
        ),
        (
            lambda s: s["close"]["action"][3].__setitem__(1, s["close"]["action"][3][1] + 1e-2),
            ["action: 1 value(s) differ by more than 0.0001, the first at index (3, 1)"],
        ),
        (
            lambda s: s["images"]["pixels"]["mean"].__setitem__(2, s["images"]["pixels"]["mean"][2] + 3),
            ["pixels mean: 1 value(s) differ by more than 0.25, the first at index (2,)"],
        ),
        (
            lambda s: s["images"]["pixels"]["thumb"][0][7][0].__setitem__(1, 255.0),
            ["pixels thumbnails: 1 value(s) differ by more than 2, the first at index (0, 7, 0, 1)"],
        ),
        (
            lambda s: s["close"].pop("action"),
            ["close keys ['privileged.pose'], recorded ['action', 'privileged.pose']"],
        ),
    ],
    ids=["one-step-longer", "done-flag", "action", "image-mean", "thumbnail", "missing-key"],
)
def test_signatures_beyond_the_tolerances_differ_with_a_message_naming_the_difference(perturb, expected):
    recorded, found = _hand_made_signature(), _hand_made_signature()
    perturb(found)
    differences = signature_differences(recorded, found)
    assert len(differences) == len(expected)
    for line, start in zip(differences, expected):
        assert line.startswith(start), line
    message = mismatch_message("ca", differences)
    assert differences[0] in message
    assert (
        "bump world or simulator or renderer or collision_avoidance_expert or collision_avoidance_episodes"
        in message
    )
    assert RECORD_COMMAND in message


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=f"Re-record {SIGNATURE_FILE.name} with the current code.")
    parser.add_argument(
        "--record", action="store_true", required=True, help="collect every kind and rewrite the file"
    )
    parser.add_argument(
        "--force", action="store_true", help="also rewrite kinds whose data differs under unchanged versions"
    )
    args = parser.parse_args()
    record(force=args.force)
