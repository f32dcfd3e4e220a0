"""Checkpoints: atomic saves, run part apart from the resume part, safe loading, clear refusals."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from navformer_rl import checkpoint as ckpt
from navformer_rl.modules import NavFormerConfig
from navformer_rl.training import build_trainer, train


@pytest.fixture
def trained(tiny_config):
    """A finished 2-iteration run (checkpoints at 1 and 2)."""
    return train(tiny_config("optim.iterations=2", "checkpoint.interval=1", "checkpoint.keep_last=0"))


def test_policy_model_loads_from_the_run_part_alone(trained):
    folder = trained.checkpoint
    (folder / ckpt.RESUME_FILENAME).unlink()  # an evaluator gets config + weights only
    config, model = ckpt.load_policy_model(trained.run_dir)
    assert isinstance(config, NavFormerConfig) and config.d_embed == 16 and not model.training
    saved = load_file(str(folder / ckpt.WEIGHTS_FILENAME))
    assert model.state_dict().keys() == saved.keys()
    assert all(torch.equal(model.state_dict()[k], saved[k]) for k in saved)
    # the loaded model predicts: same output as a second load (deterministic in eval mode)
    _, again = ckpt.load_policy_model(folder / ckpt.WEIGHTS_FILENAME)
    g = torch.Generator().manual_seed(0)
    inputs = (
        torch.randint(0, 255, (1, 84, 84, 3), dtype=torch.uint8, generator=g),
        torch.randint(0, 255, (1, 3, 84, 84, 3), dtype=torch.uint8, generator=g),
        torch.ones(1, 3, 1),
        torch.zeros(1, 3, 2),
        torch.arange(3)[None],
    )
    with torch.no_grad():
        assert torch.equal(model(*inputs), again(*inputs))
    with pytest.raises(FileNotFoundError, match="no resume part"):
        ckpt.load_resume_state(folder)


def test_resume_part_loads_with_weights_only(trained):
    state = ckpt.load_resume_state(trained.checkpoint)  # torch.load(weights_only=True) inside
    assert state["iteration"] == 2
    assert set(state["optimizers"]) == {"navformer", "dve"}
    assert state["cross_task"]["iteration"] == 2


def test_load_policy_model_refuses_other_configs_and_foreign_files(trained, tmp_path):
    config, _ = ckpt.load_policy_model(trained.run_dir)
    with pytest.raises(ValueError, match=r"another model config.*'d_embed': \(16, 128\)"):
        ckpt.load_policy_model(trained.run_dir, expected_config=NavFormerConfig())
    ckpt.load_policy_model(trained.run_dir, expected_config=config)  # same config: accepted

    # a config.json from another model next to these weights
    header_path = trained.checkpoint / ckpt.CONFIG_FILENAME
    header = json.loads(header_path.read_text())
    header["model_config"]["n_blocks"] = 2
    header_path.write_text(json.dumps(header))
    with pytest.raises(ValueError, match="different model configurations"):
        ckpt.load_policy_model(trained.checkpoint)

    # safetensors written by someone else
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / ckpt.CONFIG_FILENAME).write_text(json.dumps({"format": "other/1"}))
    save_file({"w": torch.zeros(2)}, str(foreign / ckpt.WEIGHTS_FILENAME))
    with pytest.raises(ValueError, match="not a navformer_rl training checkpoint"):
        ckpt.load_policy_model(foreign)
    with pytest.raises(FileNotFoundError, match="no checkpoint at"):
        ckpt.load_policy_model(tmp_path / "nowhere")


def test_weights_that_do_not_fit_the_config_are_refused(trained):
    weights_path = trained.checkpoint / ckpt.WEIGHTS_FILENAME
    from safetensors import safe_open

    with safe_open(str(weights_path), framework="pt") as handle:
        metadata = handle.metadata()
        state = {k: handle.get_tensor(k) for k in handle.keys()}
    state.pop("head.weight")
    save_file(state, str(weights_path), metadata=metadata)
    with pytest.raises(ValueError, match=r"does not match NavFormerModel.*missing \['head.weight'\]"):
        ckpt.load_policy_model(trained.checkpoint)


@pytest.mark.parametrize("crash_in", ["weights", "resume", "latest"])
def test_a_crash_mid_save_keeps_the_previous_checkpoint(tiny_config, monkeypatch, crash_in):
    trainer = build_trainer(tiny_config("optim.iterations=4", "checkpoint.keep_last=0"))
    trainer.step()
    first = trainer.save_checkpoint()
    before = {p.name: p.read_bytes() for p in first.iterdir()}
    trainer.step()

    def boom(*args, **kwargs):
        raise OSError("disk full (simulated)")

    target = {
        "weights": ("safetensors.torch.save_file", boom),
        "resume": ("torch.save", boom),
        "latest": ("navformer_rl.checkpoint.atomic_write_text", boom),
    }[crash_in]
    monkeypatch.setattr(*target)
    with pytest.raises(OSError, match="simulated"):
        trainer.save_checkpoint()
    monkeypatch.undo()

    root = trainer.run_dir / ckpt.CHECKPOINTS_DIRNAME
    assert ckpt.latest_checkpoint(trainer.run_dir) == first
    assert {p.name: p.read_bytes() for p in first.iterdir()} == before
    assert not [p for p in root.iterdir() if p.name.endswith(".tmp")]  # no half-written folder left behind
    ckpt.load_policy_model(trainer.run_dir)
    assert ckpt.load_resume_state(trainer.run_dir)["iteration"] == 1
    # a resumed trainer continues from iteration 1
    resumed = build_trainer(tiny_config("optim.iterations=4", "checkpoint.keep_last=0", "resume=true"))
    assert resumed.iteration == 1


def test_keep_last_prunes_old_checkpoints(tiny_config):
    result = train(tiny_config("optim.iterations=4", "checkpoint.interval=1", "checkpoint.keep_last=2"))
    names = sorted(p.name for p in (result.run_dir / ckpt.CHECKPOINTS_DIRNAME).glob("iter_*"))
    assert names == ["iter_000003", "iter_000004"]
    assert ckpt.latest_checkpoint(result.run_dir).name == "iter_000004"


def test_prune_never_removes_the_latest_checkpoint(tmp_path):
    # A crash between a folder's rename and the `latest` update leaves iter_000005 while `latest` says
    # iter_000003; the resumed run then saves iter_000004 with keep_last=2.
    def save(iteration):
        return ckpt.save_checkpoint(
            tmp_path, iteration, model_state={"w": torch.zeros(2)}, model_config={}, train_config={},
            resume_state=None, keep_last=2,
        )  # fmt: skip

    for iteration in (1, 2, 3, 5):
        save(iteration)
    (tmp_path / ckpt.CHECKPOINTS_DIRNAME / ckpt.LATEST_FILENAME).write_text("iter_000003\n")
    save(4)
    names = sorted(p.name for p in (tmp_path / ckpt.CHECKPOINTS_DIRNAME).glob("iter_*"))
    assert names == ["iter_000003", "iter_000004"]
    assert ckpt.latest_checkpoint(tmp_path).name == "iter_000004"


def test_rng_state_round_trip():
    torch.manual_seed(1)
    np.random.seed(2)
    random.seed(3)
    state = ckpt.capture_rng_state()
    expected = (torch.rand(3), np.random.rand(3), random.random())
    torch.manual_seed(99)
    np.random.seed(99)
    random.seed(99)
    ckpt.restore_rng_state(state)
    got = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(expected[0], got[0]) and np.array_equal(expected[1], got[1]) and expected[2] == got[2]
