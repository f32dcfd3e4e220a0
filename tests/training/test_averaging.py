"""Checkpoint averaging: the entry-wise mean of one run's checkpoints, written as a loadable checkpoint."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.cli.main import main
from navformer_rl.pretrained.export import write_pretrained
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training import train
from navformer_rl.training.averaging import average_checkpoints, run_checkpoints
from navformer_rl.training.pretrained_registry import CARD_FILENAME, file_sha256


def save(run_dir, iteration, state, *, seed=0, interval=1, model_config=None):
    """A run-part-only checkpoint of ``state`` (any tensors) at ``iteration``."""
    return ckpt.save_checkpoint(
        run_dir,
        iteration,
        model_state=state,
        model_config=model_config or {"d_embed": 16},
        train_config={"seed": seed, "checkpoint": {"interval": interval}},
        resume_state=None,
    )


def test_the_average_of_known_tensors(tmp_path):
    counts = torch.tensor([3, 4])
    a = save(tmp_path / "run", 1, {"w": torch.zeros(2, 3), "b": torch.tensor([1.0, -1.0]), "n": counts})
    b = save(tmp_path / "run", 2, {"w": torch.full((2, 3), 2.0), "b": torch.tensor([2.0, 0.5]), "n": counts})
    c = save(tmp_path / "run", 3, {"w": torch.full((2, 3), 7.0), "b": torch.tensor([0.0, 0.5]), "n": counts})
    out = average_checkpoints([c, a, b], tmp_path / "avg")  # any order: the sources are sorted by iteration
    state = load_file(str(out / ckpt.WEIGHTS_FILENAME))
    assert torch.equal(state["w"], torch.full((2, 3), 3.0))
    assert torch.equal(state["b"], torch.tensor([1.0, 0.0]))
    assert torch.equal(state["n"], counts) and state["n"].dtype == counts.dtype
    header = ckpt.read_checkpoint_config(out)
    assert header["iteration"] == 3 and header["train_config"]["seed"] == 0
    assert header["run"]["averaged_from"] == [
        {
            "checkpoint": str(folder),
            "iteration": i,
            "weights_sha256": file_sha256(folder / ckpt.WEIGHTS_FILENAME),
        }
        for i, folder in ((1, a), (2, b), (3, c))
    ]
    assert ckpt.resolve_checkpoint(out) == out


def test_a_trained_runs_average_loads_as_a_policy_and_goes_on_its_model_card(tiny_config, tmp_path):
    trained = train(tiny_config("optim.iterations=3", "checkpoint.interval=1", "checkpoint.keep_last=0"))
    sources = run_checkpoints(trained.run_dir, 1, 3)
    assert [folder.name for folder in sources] == ["iter_000001", "iter_000002", "iter_000003"]
    out = average_checkpoints(sources, tmp_path / "avg")
    _, model = ckpt.load_policy_model(out)
    states = [load_file(str(folder / ckpt.WEIGHTS_FILENAME)) for folder in sources]
    for key, tensor in model.state_dict().items():
        expected = sum(state[key].double() for state in states) / 3
        assert torch.equal(tensor, expected.float()), key
    assert any(not torch.equal(model.state_dict()[k], states[-1][k]) for k in states[-1])  # not the last one
    shipped = write_pretrained(out, "navformer_avg", out_dir=tmp_path / "pretrained")
    card = (shipped / CARD_FILENAME).read_text()
    assert "the uniform mean of 3 checkpoints of the run (iterations 1, 2, 3" in card


def test_run_checkpoints_takes_the_regular_ones_in_the_range(tmp_path):
    run = tmp_path / "run"
    for iteration in (2, 3, 4, 6):  # 3: a checkpoint a stop wrote between two intervals of 2
        save(run, iteration, {"w": torch.zeros(1)}, interval=2)
    assert [f.name for f in run_checkpoints(run, 2, 5)] == ["iter_000002", "iter_000004"]
    assert [f.name for f in run_checkpoints(run, 0, 100)] == ["iter_000002", "iter_000004", "iter_000006"]
    with pytest.raises(ValueError, match="has 1 regular checkpoint"):
        run_checkpoints(run, 5, 6)
    with pytest.raises(ValueError, match="first iteration 6 is after last iteration 2"):
        run_checkpoints(run, 6, 2)
    with pytest.raises(FileNotFoundError, match="no run directory"):
        run_checkpoints(tmp_path / "missing", 0, 1)


def test_averaging_refuses_what_is_not_one_run(tmp_path):
    a = save(tmp_path / "a", 1, {"w": torch.zeros(2)})
    b = save(tmp_path / "a", 2, {"w": torch.ones(2)})
    with pytest.raises(ValueError, match="at least 2 distinct checkpoints"):
        average_checkpoints([a], tmp_path / "out")
    with pytest.raises(ValueError, match="at least 2 distinct checkpoints"):
        average_checkpoints([a, a], tmp_path / "out")
    other_seed = save(tmp_path / "s1", 2, {"w": torch.ones(2)}, seed=1)
    with pytest.raises(ValueError, match="come from different runs"):
        average_checkpoints([a, other_seed], tmp_path / "out")
    other_model = save(tmp_path / "m", 2, {"w": torch.ones(2)}, model_config={"d_embed": 32})
    with pytest.raises(ValueError, match=r"different model configurations \(fields \['d_embed'\]\)"):
        average_checkpoints([a, other_model], tmp_path / "out")
    other_shape = save(tmp_path / "shape", 3, {"w": torch.ones(3)})
    with pytest.raises(ValueError, match="does not hold the same tensors"):
        average_checkpoints([a, other_shape], tmp_path / "out")
    counts = (
        save(tmp_path / "n", 1, {"n": torch.tensor([1])}),
        save(tmp_path / "n", 2, {"n": torch.tensor([2])}),
    )
    with pytest.raises(ValueError, match="non-float entries cannot be averaged"):
        average_checkpoints(counts, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    average_checkpoints([a, b], tmp_path / "out")
    with pytest.raises(FileExistsError, match="already exists"):
        average_checkpoints([a, b], tmp_path / "out")
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="is a file"):
        average_checkpoints([a, b], tmp_path / "file")


def test_overwrite_replaces_the_folder(tmp_path):
    a = save(tmp_path / "a", 1, {"w": torch.zeros(2)})
    b = save(tmp_path / "a", 2, {"w": torch.ones(2)})
    c = save(tmp_path / "a", 3, {"w": torch.full((2,), 4.0)})
    average_checkpoints([a, b], tmp_path / "out")
    average_checkpoints([a, b, c], tmp_path / "out", overwrite=True)
    assert torch.equal(load_file(str(tmp_path / "out" / ckpt.WEIGHTS_FILENAME))["w"], torch.full((2,), 5 / 3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "out"]  # no temporary folder left


def test_cli(tmp_path, capsys):
    run = tmp_path / "run"
    for iteration in (1, 2, 3):
        save(run, iteration, {"w": torch.full((2,), float(iteration))})
    out = tmp_path / "avg"
    assert (
        main(["average-checkpoints", "--run", str(run), "--first", "2", "--last", "3", "--out", str(out)])
        == 0
    )
    assert f"averaged 2 checkpoints (iterations 2, 3) -> {out}" in capsys.readouterr().out
    assert json.loads((out / ckpt.CONFIG_FILENAME).read_text())["iteration"] == 3
    assert torch.equal(load_file(str(out / ckpt.WEIGHTS_FILENAME))["w"], torch.full((2,), 2.5))
    listed = ["average-checkpoints", "--checkpoint", str(run / "checkpoints/iter_000001"), str(run), "--out"]
    assert main([*listed, str(out)]) == 2
    assert capsys.readouterr().err.strip().endswith("already exists; pass overwrite (--force) to replace it")
    assert main([*listed, str(out), "--force"]) == 0
    assert torch.equal(load_file(str(out / ckpt.WEIGHTS_FILENAME))["w"], torch.full((2,), 2.0))
    assert main(["average-checkpoints", "--run", str(run), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == (
        "navformer average-checkpoints: error: --run needs --first and --last "
        "(the iterations to average between)"
    )
    assert main(["average-checkpoints", "--checkpoint", str(run), "--first", "1", "--out", str(out)]) == 2
    assert "with --checkpoint list them instead" in capsys.readouterr().err
