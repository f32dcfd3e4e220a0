"""Data-parallel training: 2 gloo CPU processes equal one process with the same global batch; every process
holds the same weights and BYOL target; only rank 0 writes; a data-parallel run resumes bit-identically and
refuses another world size.

One spawn of 2 processes (``torch.multiprocessing``) runs every data-parallel scenario through ``train()``
with ``torchrun``'s environment variables set, so the process group is started the way ``torchrun`` gets it.
Those tests share it and are marked slow (two processes importing torch and TorchRL: ~25 s of CPU, over a
minute on a busy 2-core machine); the unit tests of the split, the augmentation and the refusals are not.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.training import build_trainer, load_train_config, train
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.distributed import Distributed, ShardedAugmentation, launch_environment, shard_rows

from .conftest import TINY_OVERRIDES, data_overrides
from .test_recipe import ROOT
from .test_resume import scalars

WORLD_SIZE = 2
COMMON = [
    "model.dropout=0.0",  # dropout masks are drawn per process: the one difference from one process
    "data.exploration_batch_trajs=3",  # 2 + 1 trajectories: an uneven split
    "data.collision_batch_trajs=4",
    "data.ssl_batch_pairs=5",  # 3 + 2 pairs: BYOL's BatchNorm over the global batch
    "optim.iterations=4",
    "checkpoint.keep_last=0",
    "device=cpu",
]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _worker(rank: int, base: list[str], out: str, ports: list[int]) -> None:
    """One process of the data-parallel runs: a straight 4-iteration run, then a run that checkpoints at 2,
    logs iteration 3 and "crashes", then its resume, then a run whose rank 1 gets SIGTERM after iteration 1.
    Saves what the parent checks to ``out/rank<r>.pt``."""
    from navformer_rl.training import distributed, run
    from navformer_rl.training.trainer import Trainer

    torch.set_num_threads(1)
    os.environ.update(
        MASTER_ADDR="127.0.0.1", RANK=str(rank), WORLD_SIZE=str(WORLD_SIZE), LOCAL_RANK=str(rank)
    )
    os.environ[distributed.TIMEOUT_VARIABLE] = "120"
    writes: list[str] = []
    trainers: list[Trainer] = []

    def recorded(name, function):
        def call(*args, **kwargs):
            writes.append(name)
            return function(*args, **kwargs)

        return call

    ckpt.save_checkpoint = recorded("checkpoint", ckpt.save_checkpoint)
    run.atomic_write_text = recorded("train_config.json", run.atomic_write_text)
    Trainer.make_logger = recorded("logger", Trainer.make_logger)
    build = run.build_trainer
    run.build_trainer = lambda cfg: trainers.append(build(cfg)) or trainers[-1]

    def config(*overrides: str):
        return load_train_config([*base, *overrides])

    os.environ["MASTER_PORT"] = str(ports[0])
    train(config(f"output_dir={out}/straight", "checkpoint.interval=2"))
    interrupted = [f"output_dir={out}/interrupted", "checkpoint.interval=2"]
    os.environ["MASTER_PORT"] = str(ports[1])
    with distributed.process_group("cpu") as process:
        trainer = build(config(*interrupted), process)
        for _ in range(2):
            trainer.record(trainer.step())
        trainer.save_checkpoint()
        trainer.record(trainer.step())  # logged after the checkpoint, then lost
        trainer.close()
    os.environ["MASTER_PORT"] = str(ports[2])
    train(config(*interrupted, "resume=true"))
    straight, resumed = trainers[:2]

    # SIGTERM to rank 1 alone, after iteration 1: every process saves iteration 1 and stops
    step = Trainer.step

    def step_then_signal(self: Trainer) -> dict[str, float]:
        metrics = step(self)
        if rank == 1 and self.iteration == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        return metrics

    Trainer.step = step_then_signal
    os.environ["MASTER_PORT"] = str(ports[3])
    try:
        train(config(f"output_dir={out}/signalled", "checkpoint.interval=100"))
        stopped_by = None
    except KeyboardInterrupt as interrupt:
        stopped_by = type(interrupt).__name__
    finally:
        Trainer.step = step
    torch.save(
        {
            "writes": writes,
            "distributed": straight.distributed.run_info(),
            "model": straight.model.state_dict(),
            "byol": straight.byol_loss.state_dict(),
            "optimizers": {k: o.state_dict()["state"] for k, o in straight.optimizers.items()},
            "resumed_byol": resumed.byol_loss.state_dict(),
            "logger": straight.logger is not None,
            "stopped_by": stopped_by,
        },
        f"{out}/rank{rank}.pt",
    )


@pytest.fixture(scope="module")
def runs(datasets, tmp_path_factory) -> dict:
    """The data-parallel runs (2 processes) and one process's run of the same global batches."""
    out = tmp_path_factory.mktemp("distributed")
    base = [*data_overrides(datasets), *TINY_OVERRIDES, *COMMON]
    ports = [free_port() for _ in range(4)]
    torch.multiprocessing.spawn(_worker, args=(base, str(out), ports), nprocs=WORLD_SIZE, join=True)
    single = train(load_train_config([*base, f"output_dir={out / 'single'}", "checkpoint.interval=4"]))
    ranks = [torch.load(out / f"rank{r}.pt", weights_only=True) for r in range(WORLD_SIZE)]
    return {"out": out, "single": single.run_dir, "ranks": ranks, "base": base}


def weights(run_dir: Path, iteration: int) -> dict[str, torch.Tensor]:
    return load_file(str(run_dir / "checkpoints" / f"iter_{iteration:06d}" / "model.safetensors"))


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_two_processes_train_as_one_process_on_the_same_global_batches(runs):
    single, parallel = runs["single"], runs["out"] / "straight"
    for name in ("loss", "loss_dt", "loss_byol", "byol_static", "byol_general", "frames"):
        one, two = scalars(single, name), scalars(parallel, name)
        assert [s for s, _ in two] == [1, 2, 3, 4], name
        assert [v for _, v in two] == pytest.approx([v for _, v in one], rel=1e-5), name
    # Adam's moments accumulate the gradients: the summed per-process gradients are the global batch's, to
    # 1e-5 of each optimiser's moments (measured 1e-5; with per-process BatchNorm statistics: 0.8-1.7).
    # Compared over all of an optimiser's tensors: a bias right before BatchNorm has a zero gradient up to
    # rounding, which no tolerance relative to the tensor itself can compare.
    sa = ckpt.load_resume_state(single / "checkpoints" / "iter_000004")["optimizers"]
    sb = ckpt.load_resume_state(parallel / "checkpoints" / "iter_000004")["optimizers"]
    for name, state in sa.items():
        for key in ("exp_avg", "exp_avg_sq"):
            expected = torch.cat([entry[key].flatten() for entry in state["state"].values()])
            got = torch.cat([entry[key].flatten() for entry in sb[name]["state"].values()])
            assert float((got - expected).norm() / expected.norm()) < 1e-4, (name, key)
    # Adam divides by the gradient's root mean square, so where a gradient is near zero the rounding of the
    # summation order moves a weight by a fraction of lr (2e-4) per step: a quarter of one step
    wa, wb = weights(single, 4), weights(parallel, 4)
    assert wa.keys() == wb.keys()
    for key in wa:
        torch.testing.assert_close(wb[key], wa[key], rtol=0, atol=5e-5, msg=key)
    # BYOL: online networks and heads (as the weights), EMA target, BatchNorm statistics of the global batch.
    # The heads' first bias feeds BatchNorm, which cancels it: its gradient is rounding noise in both runs,
    # so Adam moves it (and the running mean after it) by up to lr per step either way; it is left out.
    ra = ckpt.load_resume_state(single / "checkpoints" / "iter_000004")["byol"]
    rb = ckpt.load_resume_state(parallel / "checkpoints" / "iter_000004")["byol"]
    assert ra.keys() == rb.keys() and any("running_var" in key for key in ra)
    cancelled = re.compile(r"(projector|predictor_params\.\w+)\.(0\.bias|1\.running_mean)$")
    compared = [key for key in ra if not cancelled.search(key)]
    assert len(compared) == len(ra) - 12  # 2 encoders x (online, target, predictor) x (bias, mean)
    for key in compared:
        torch.testing.assert_close(rb[key].double(), ra[key].double(), rtol=1e-4, atol=5e-5, msg=key)


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_every_process_holds_the_same_weights_byol_target_and_optimiser_state(runs):
    first, second = runs["ranks"]
    for part in ("model", "byol", "resumed_byol"):
        assert first[part].keys() == second[part].keys()
        for key in first[part]:
            assert torch.equal(first[part][key], second[part][key]), (part, key)
    assert any(key.startswith("target_online_network_params") for key in first["byol"])
    for name, state in first["optimizers"].items():
        for index, entry in state.items():
            for key, value in entry.items():
                assert torch.equal(value, second["optimizers"][name][index][key]), (name, index, key)


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_only_rank_0_writes_and_the_run_records_its_world_size(runs):
    first, second = runs["ranks"]
    assert second["writes"] == [] and not second["logger"]
    assert "checkpoint" in first["writes"] and "train_config.json" in first["writes"] and first["logger"]
    assert first["distributed"] == {"world_size": 2, "backend": "gloo"}
    parallel = runs["out"] / "straight"
    recorded = json.loads((parallel / "train_config.json").read_text())
    assert recorded["run"] == {"world_size": 2, "backend": "gloo", "init_from": None}
    header = ckpt.read_checkpoint_config(parallel)
    assert header["run"]["world_size"] == 2 and ckpt.recorded_world_size(header) == 2
    state = ckpt.load_resume_state(parallel)
    assert len(state["rng_ranks"]) == 2 and not torch.equal(
        state["rng_ranks"][0]["torch"], state["rng_ranks"][1]["torch"]
    )
    assert [s for s, _ in scalars(parallel, "loss")] == [1, 2, 3, 4]  # one row per iteration: one writer


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_a_resumed_data_parallel_run_equals_the_uninterrupted_one(runs):
    straight, interrupted = runs["out"] / "straight", runs["out"] / "interrupted"
    for name in ("loss", "loss_dt", "loss_byol"):
        # the row logged after the checkpoint (iteration 3) was dropped, then logged again identically
        assert scalars(interrupted, name) == scalars(straight, name), name
    wa, wb = weights(straight, 4), weights(interrupted, 4)
    assert all(torch.equal(wa[key], wb[key]) for key in wa)
    first, _ = runs["ranks"]
    assert all(torch.equal(first["byol"][key], first["resumed_byol"][key]) for key in first["byol"])


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_sigterm_to_one_process_checkpoints_every_process_after_the_same_iteration(runs):
    assert [rank["stopped_by"] for rank in runs["ranks"]] == ["Terminated", "Terminated"]
    signalled = runs["out"] / "signalled"
    assert sorted(p.name for p in (signalled / "checkpoints").glob("iter_*")) == ["iter_000001"]
    assert len(ckpt.load_resume_state(signalled)["rng_ranks"]) == 2  # both processes took part in the save


@pytest.mark.slow  # the `runs` fixture: 2 spawned processes, ~25 s of CPU
def test_resuming_with_another_number_of_processes_is_refused(runs, tmp_path):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(runs["out"] / "straight", copy)
    cfg = load_train_config([*runs["base"], f"output_dir={copy}", "resume=true", "optim.iterations=5"])
    with pytest.raises(ValueError, match=r"with 1 process\(es\): it was written by 2 .*--nproc-per-node 2$"):
        build_trainer(cfg)


def test_global_batches_split_into_contiguous_near_equal_rows():
    assert [shard_rows(25, r, 2) for r in range(2)] == [slice(0, 13), slice(13, 25)]
    assert [shard_rows(150, r, 4) for r in range(4)] == [
        slice(0, 38),
        slice(38, 76),
        slice(76, 113),
        slice(113, 150),
    ]
    with pytest.raises(ValueError, match="a global batch of 1 cannot be split over 2 processes"):
        shard_rows(1, 0, 2)


def test_a_process_augments_its_rows_as_one_process_augments_the_whole_batch():
    from navformer_rl.objectives.byol_augment import BYOLAugmentation

    pixels = torch.randint(
        0, 256, (5, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0)
    )
    whole = BYOLAugmentation(seed=3)
    parts = [ShardedAugmentation(rows=shard_rows(5, r, 2), total=5, seed=3) for r in range(2)]
    for _ in range(2):  # the generators stay in step
        expected = whole(pixels)
        got = torch.cat([part(pixels[part.rows]) for part in parts])
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-6)
    assert all(torch.equal(part.rng_state(), whole.rng_state()) for part in parts)
    with pytest.raises(ValueError, match="takes rows 0-2 \\(3 images\\); got 5"):
        parts[0](pixels)


def test_a_batch_smaller_than_the_world_and_bad_launch_variables_are_refused(tiny_config, monkeypatch):
    cfg = tiny_config("data.exploration_batch_trajs=2")
    with pytest.raises(ValueError, match=r"data.exploration_batch_trajs=2 is smaller than the 3 processes"):
        build_trainer(cfg, Distributed(rank=0, world_size=3, backend="gloo"))
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "two")
    with pytest.raises(ValueError, match="RANK='two': expected an integer"):
        launch_environment()
    monkeypatch.setenv("RANK", "2")
    with pytest.raises(ValueError, match="expected 0 <= RANK < WORLD_SIZE"):
        launch_environment()
    monkeypatch.setenv("RANK", "0")
    with pytest.raises(RuntimeError, match="torchrun started 2 processes but no process group"):
        build_trainer(cfg)


def test_the_recipe_under_torchrun_needs_an_output_dir(monkeypatch):
    from .test_recipe import recipe_config

    monkeypatch.setenv("WORLD_SIZE", "2")
    with pytest.raises(ValueError, match="under torchrun the recipe needs output_dir=<run directory>"):
        recipe_config()
    assert recipe_config("output_dir=/runs/a").output_dir == "/runs/a"


@pytest.mark.slow
@pytest.mark.parametrize("entry", ["navformer train", "recipe"])
def test_torchrun_runs_the_training_commands(datasets, tmp_path, entry):
    """``torchrun --nproc-per-node 2 -m navformer_rl train ...`` and
    ``torchrun ... recipes/navformer/navformer.py``: the real launcher and entry points."""
    out = tmp_path / "run"
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]
    script = (
        ["-m", "navformer_rl", "train"]
        if entry == "navformer train"
        else [str(ROOT / "recipes/navformer/navformer.py")]
    )
    overrides = [
        *data_overrides(datasets),
        *TINY_OVERRIDES,
        *COMMON,
        "optim.iterations=2",
        f"output_dir={out}",
    ]
    if entry == "recipe":
        overrides.append(f"hydra.run.dir={out}")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RL_WARNINGS": "0"}
    done = subprocess.run(
        [*launcher, *script, *overrides], capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("trained 2 iterations") == 1  # rank 0 prints the summary
    assert json.loads((out / "train_config.json").read_text())["run"]["world_size"] == 2
    assert ckpt.latest_checkpoint(out).name == "iter_000002"
    assert [s for s, _ in scalars(out, "loss")] == [1, 2]
