"""A list of dataset folders trains exactly as one folder holding the same trajectories in the same order."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.cli.main import main as navformer_main
from navformer_rl.data import make_synthetic_dataset, open_dataset
from navformer_rl.data.concat import ConcatNavDataset, concat_datasets
from navformer_rl.data.writer import DatasetWriter
from navformer_rl.training import load_train_config, train
from navformer_rl.training.datasets import open_datasets

from .conftest import TINY_OVERRIDES


def one_folder(root: Path, kind: str, parts: list[Path]) -> Path:
    """A dataset folder holding the trajectories of ``parts`` in order (shard ``i`` = part ``i``)."""
    datasets = [open_dataset(part) for part in parts]
    total = sum(d.num_trajectories for d in datasets)
    writer = DatasetWriter(root, kind, {"joined": [str(p) for p in parts]}, target_count=total)
    for unit, dataset in enumerate(datasets):
        rows = dataset.rows.to_tensordict()
        writer.write_shard(unit, rows, dataset.targets.as_subclass(torch.Tensor).clone(), {})
    return writer.finalize()


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """Two D_e and two D_ca parts (other seeds and lengths), the folders joining each pair (D_ca's both
    ways), and a D_ssl."""
    root = tmp_path_factory.mktemp("lists")
    out = {
        "e0": make_synthetic_dataset(root / "e0", "e", 5, 4, 10, seed=21),
        "e1": make_synthetic_dataset(root / "e1", "e", 3, 6, 14, seed=22),
        "ca0": make_synthetic_dataset(root / "ca0", "ca", 6, 3, 7, seed=23),
        "ca1": make_synthetic_dataset(root / "ca1", "ca", 7, 2, 9, seed=24),
        "ssl": make_synthetic_dataset(root / "ssl", "ssl", 16, seed=25),
    }
    out["e"] = one_folder(root / "e", "e", [out["e0"], out["e1"]])
    out["ca"] = one_folder(root / "ca", "ca", [out["ca0"], out["ca1"]])
    out["ca_reversed"] = one_folder(root / "ca_reversed", "ca", [out["ca1"], out["ca0"]])
    return out


VALIDATION = (
    "validation/loss_dt_exploration",
    "validation/train_loss_dt_exploration",
    "validation/loss_dt_collision_avoidance",
    "validation/train_loss_dt_collision_avoidance",
)
"""Held-out losses (D_ca's a list of two folders) and the training windows' losses."""


def scalars(run_dir: Path, name: str) -> list[str]:
    """The rows of a logged scalar's CSV file."""
    return (run_dir / "logs" / "navformer" / "scalars" / f"{name}.csv").read_text().splitlines()


def assert_same_batch(a, b) -> None:
    assert a.keys(True, True) and set(a.keys(True, True)) == set(b.keys(True, True))
    for key in a.keys(True, True):
        assert torch.equal(a[key], b[key]), key


@pytest.mark.parametrize("head", [None, 6, 4], ids=["all", "head-across-parts", "head-in-first"])
def test_a_list_draws_the_batches_of_the_joined_folder(folders, head):
    joined = open_dataset(folders["e"])
    listed = concat_datasets([open_dataset(folders["e0"]), open_dataset(folders["e1"])])
    assert (
        isinstance(listed, ConcatNavDataset) and listed.num_trajectories == 8 and len(listed) == len(joined)
    )
    if head is not None:
        joined, listed = joined.head(head), listed.head(head)
    assert listed.num_trajectories == joined.num_trajectories
    for name in ("start", "length", "target_id"):
        assert torch.equal(getattr(listed.episodes, name), getattr(joined.episodes, name)), name
    options = {"context_steps": 5, "seed": 3, "buffer_sets": 2}
    a = joined.trajectory_batcher(3, **options)
    b = listed.trajectory_batcher(3, **options)
    for _ in range(6):  # two epochs and more: windows, offsets and buffer reuse
        assert_same_batch(a.sample(), b.sample())
    fresh = listed.trajectory_batcher(2, 5, seed=3, reuse_buffers=False)
    assert_same_batch(joined.trajectory_batcher(2, 5, seed=3, reuse_buffers=False).sample(), fresh.sample())


def test_training_on_a_list_equals_training_on_the_joined_folder(folders, tmp_path):
    common = [
        *TINY_OVERRIDES,
        f"data.ssl_path={folders['ssl']}",
        "optim.iterations=4",
        "checkpoint.interval=4",
    ]
    common += [f"validation.exploration_path={folders['e1']}", "validation.interval=2"]
    listed_paths = [
        f"data.exploration_path=[{folders['e0']},{folders['e1']}]",
        f"data.collision_path=[{folders['ca0']},{folders['ca1']}]",
        "data.exploration_trajectories=7",  # the first 7 of the concatenation: the list's boundary is crossed
        f"validation.collision_path=[{folders['ca1']},{folders['ca0']}]",
    ]
    joined_paths = [
        f"data.exploration_path={folders['e']}",
        f"data.collision_path={folders['ca']}",
        "data.exploration_trajectories=7",
        f"validation.collision_path={folders['ca_reversed']}",
    ]
    listed = train(load_train_config([*common, *listed_paths, f"output_dir={tmp_path / 'listed'}"]))
    joined = train(load_train_config([*common, *joined_paths, f"output_dir={tmp_path / 'joined'}"]))
    for name in ("loss_dt_exploration", "loss_dt_collision_avoidance", "loss_byol", *VALIDATION):
        a, b = scalars(listed.run_dir, name), scalars(joined.run_dir, name)
        assert a and a == b, name
    wa = load_file(str(listed.checkpoint / "model.safetensors"))
    wb = load_file(str(joined.checkpoint / "model.safetensors"))
    assert wa.keys() == wb.keys()
    for key in wa:
        assert torch.equal(wa[key], wb[key]), key
    recorded = json.loads((listed.run_dir / "train_config.json").read_text())["data"]
    assert recorded["exploration_path"] == [str(folders["e0"]), str(folders["e1"])]
    assert recorded["collision_path"] == [str(folders["ca0"]), str(folders["ca1"])]


def test_one_folder_in_a_list_is_that_folder(folders):
    cfg = load_train_config([*TINY_OVERRIDES, f"data.exploration_path=[{folders['e0']}]", "ablation=no_ssl"])
    cfg.data.collision_path = str(folders["ca0"])
    datasets = open_datasets(cfg)
    assert type(datasets["e"]).__name__ == "NavDataset" and datasets["e"].root == folders["e0"]


@pytest.mark.parametrize(
    ("paths", "expected"),
    [
        ("[{e0},{ca0}]", "data.exploration_path[1]: {ca0} holds a 'ca' dataset, expected 'e'"),
        ("[{e0},{e0}/missing]", "data.exploration_path[1]='{e0}/missing' does not exist"),
        ("[{e0},{ssl}]", "data.exploration_path[1]: {ssl} holds a 'ssl' dataset, expected 'e'"),
        ("[]", "data.exploration_path=[]: expected null, a dataset folder or a non-empty list"),
    ],
    ids=["other-kind", "missing", "ssl", "empty"],
)
def test_bad_lists_are_one_line_errors(folders, tmp_path, capsys, paths, expected):
    argv = [
        "train",
        f"data.exploration_path={paths.format(**folders)}",
        f"data.collision_path={folders['ca0']}",
        f"data.ssl_path={folders['ssl']}",
        *TINY_OVERRIDES,
        "optim.iterations=1",
        f"output_dir={tmp_path / 'run'}",
    ]
    assert navformer_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("navformer train: error: "), err
    assert expected.format(**folders) in err[0]
    assert not (tmp_path / "run" / "checkpoints").exists()
