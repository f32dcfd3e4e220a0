"""Checkpoints: atomic saves, run part apart from the resume part, safe loading, clear refusals."""

from __future__ import annotations

import json
import os
import random
import re
import stat

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from navformer_rl.modules import NavFormerConfig
from navformer_rl.training import build_trainer, train
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.utils import durable


@pytest.fixture
def trained(tiny_config):
    """A finished 2-iteration run (checkpoints at 1 and 2)."""
    return train(tiny_config("optim.iterations=2", "checkpoint.interval=1", "checkpoint.keep_last=0"))


def test_policy_model_loads_from_the_run_part_alone(tiny_config, monkeypatch):
    from navformer_rl.training import run as run_module

    built = []

    def keep_the_trainer(cfg):
        built.append(build_trainer(cfg))
        return built[-1]

    monkeypatch.setattr(run_module, "build_trainer", keep_the_trainer)
    trained = train(tiny_config("optim.iterations=2", "checkpoint.interval=1", "checkpoint.keep_last=0"))
    (trainer,) = built
    assert trained.iterations == 2 and trained.checkpoint.name == "iter_000002"
    folder = trained.checkpoint
    (folder / ckpt.RESUME_FILENAME).unlink()  # an evaluator gets config + weights only
    config, model = ckpt.load_policy_model(trained.run_dir)
    assert isinstance(config, NavFormerConfig) and config.d_embed == 16 and not model.training
    saved = load_file(str(folder / ckpt.WEIGHTS_FILENAME))
    assert model.state_dict().keys() == saved.keys()
    assert all(torch.equal(model.state_dict()[k], saved[k]) for k in saved)
    # the loaded model predicts what the trained model (in memory, after its last step) predicts
    trained_model = trainer.model.eval()
    g = torch.Generator().manual_seed(0)
    inputs = (
        torch.randint(0, 255, (1, 84, 84, 3), dtype=torch.uint8, generator=g),
        torch.randint(0, 255, (1, 3, 84, 84, 3), dtype=torch.uint8, generator=g),
        torch.ones(1, 3, 1),
        torch.zeros(1, 3, 2),
        torch.arange(3)[None],
    )
    with torch.no_grad():
        expected = trained_model(*inputs)
        assert torch.equal(model(*inputs), expected)
        # not what any model predicts: the first checkpoint (one step earlier) predicts otherwise
        _, earlier = ckpt.load_policy_model(folder.parent / "iter_000001")
        assert not torch.equal(expected, earlier(*inputs))
    with pytest.raises(FileNotFoundError, match="no resume part"):
        ckpt.load_resume_state(folder)


def test_every_documented_checkpoint_path_form_loads(trained):
    run_dir, folder = trained.run_dir, trained.checkpoint
    root = run_dir / ckpt.CHECKPOINTS_DIRNAME
    forms = [
        run_dir,
        root,  # `navformer evaluate --checkpoint runs/nav/checkpoints`
        root / ckpt.LATEST_FILENAME,  # `--checkpoint runs/nav/checkpoints/latest`
        folder,
        folder / ckpt.WEIGHTS_FILENAME,
        folder / ckpt.CONFIG_FILENAME,
    ]
    for form in forms:
        assert ckpt.resolve_checkpoint(form) == folder, form
        assert ckpt.resolve_checkpoint(str(form)) == folder, form
    config, _ = ckpt.load_policy_model(root)
    assert config.d_embed == 16
    ckpt.load_policy_model(root / ckpt.LATEST_FILENAME)


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


def _as_batchnorm_resnet18(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The state dict the ResNet18 encoder had before GroupNorm:
    ``bn1``/``bn2`` names and running statistics."""
    old = {}
    for key, value in state.items():
        key = key.replace(".norm1.", ".bn1.").replace(".norm2.", ".bn2.")
        old[key] = value
        layer, _, name = key.rpartition(".")
        if name == "bias" and re.search(r"(stem\.1|\.bn[12]|shortcut\.1)$", layer):
            old[f"{layer}.running_mean"] = torch.zeros_like(value)
            old[f"{layer}.running_var"] = torch.ones_like(value)
            old[f"{layer}.num_batches_tracked"] = torch.zeros((), dtype=torch.long)
    return old


def test_a_batchnorm_resnet18_checkpoint_is_refused_clearly(tiny_config):
    """ResNet18 checkpoints written before BatchNorm became GroupNorm neither load nor resume (ValueError)."""
    small = ["ablation=resnet18", "data.collision_batch_trajs=2", "data.ssl_batch_pairs=2"]
    result = train(tiny_config(*small, "optim.iterations=1"))
    weights_path = result.checkpoint / ckpt.WEIGHTS_FILENAME
    from safetensors import safe_open

    with safe_open(str(weights_path), framework="pt") as handle:
        metadata = handle.metadata()
        state = {k: handle.get_tensor(k) for k in handle.keys()}
    old = _as_batchnorm_resnet18(state)
    assert (
        "dve.general_encoder.stem.1.running_mean" in old and "dve.general_encoder.stages.0.bn1.weight" in old
    )
    save_file(old, str(weights_path), metadata=metadata)
    match = (
        r"does not match NavFormerModel.*missing \['dve.general_encoder.stages.0.norm1.bias'.*running_mean"
    )
    with pytest.raises(ValueError, match=match):
        ckpt.load_policy_model(result.run_dir)
    with pytest.raises(ValueError, match=match):
        train(tiny_config(*small, "optim.iterations=2", "resume=true"))


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
        "latest": ("navformer_rl.training.checkpoint.atomic_write_text", boom),
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


def _save_tiny(run_dir, iteration=1, keep_last=0):
    return ckpt.save_checkpoint(
        run_dir, iteration, model_state={"w": torch.zeros(2)}, model_config={}, train_config={},
        resume_state={"iteration": iteration}, keep_last=keep_last,
    )  # fmt: skip


def test_other_paths_are_refused_with_the_accepted_forms(tmp_path):
    _save_tiny(tmp_path / "run")
    accepted = (
        r"a run directory .* its checkpoints/ folder or the checkpoints/latest file .* a checkpoint folder"
    )
    for wrong in (
        tmp_path,
        tmp_path / "run" / "logs",
        tmp_path / "nowhere",
        tmp_path / "nowhere" / "checkpoints",
    ):
        with pytest.raises(FileNotFoundError, match=f"no checkpoint at .*: expected {accepted}"):
            ckpt.resolve_checkpoint(wrong)
    (tmp_path / "stray.txt").write_text("x")
    with pytest.raises(FileNotFoundError, match=accepted):
        ckpt.resolve_checkpoint(tmp_path / "stray.txt")
    # checkpoints/ without `latest`: a run that has not completed its first checkpoint
    (tmp_path / "early" / ckpt.CHECKPOINTS_DIRNAME).mkdir(parents=True)
    for early in (tmp_path / "early", tmp_path / "early" / ckpt.CHECKPOINTS_DIRNAME):
        with pytest.raises(FileNotFoundError, match="no complete checkpoint .* yet: no latest pointer"):
            ckpt.resolve_checkpoint(early)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002], ids=oct)
def test_checkpoints_get_the_modes_of_the_umask(tmp_path, monkeypatch, umask):
    """mkdtemp / mkstemp / safetensors create owner-only (0700 / 0600) entries; a checkpoint must be
    readable by whoever the umask lets read, like any file the run writes with open()."""
    monkeypatch.setattr(durable, "_UMASK", umask)  # what navformer_rl.utils.durable read at import time
    previous = os.umask(umask)
    try:
        folder = _save_tiny(tmp_path / "run")
        _save_tiny(tmp_path / "run", iteration=1)  # the same iteration saved again (replaces the folder)
        ckpt.atomic_write_text(tmp_path / "run" / "train_config.json", "{}")
    finally:
        os.umask(previous)

    def mode(path):
        return stat.S_IMODE(path.stat().st_mode)

    root = folder.parent
    assert {p.name for p in folder.iterdir()} == {"config.json", "model.safetensors", "resume.pt"}
    assert mode(folder) == 0o777 & ~umask
    for path in (*folder.iterdir(), root / ckpt.LATEST_FILENAME, tmp_path / "run" / "train_config.json"):
        assert mode(path) == 0o666 & ~umask, path.name
    assert not [p for p in root.iterdir() if p.name.startswith(".")]


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
