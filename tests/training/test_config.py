"""Configuration: packaged defaults are the paper's, overrides, ablation mapping, and clear errors for bad
configurations - raised before any training starts (nothing is written)."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import shutil
import warnings
from pathlib import Path

import pytest
import yaml

from navformer_rl.training import (
    ABLATIONS,
    TrainConfig,
    build_trainer,
    load_train_config,
    model_config,
    printable_config,
)


def test_packaged_defaults_are_the_papers():
    cfg = load_train_config()
    assert cfg == TrainConfig(model=cfg.model)
    assert (cfg.optim.lr, cfg.optim.weight_decay) == (2e-4, 1e-4)  # AdamW, §VI
    assert (cfg.optim.dve_lr, cfg.optim.dve_weight_decay) == (4e-4, 4e-4)  # Adam, §VI
    assert cfg.optim.iterations == 10_000
    batches = (cfg.data.exploration_batch_trajs, cfg.data.collision_batch_trajs, cfg.data.ssl_batch_pairs)
    assert batches == (25, 150, 512)
    model = model_config(cfg)
    assert (model.d_embed, model.n_blocks, model.n_heads, model.d_head, model.context_tokens) == (
        128,
        3,
        2,
        64,
        1024,
    )
    assert model.dropout == 0.1 and model.thsc and model.use_static_encoder and model.use_general_encoder
    assert not model.detach_encoders  # eq. 11: L_DT trains the encoders too


def test_overrides_reach_the_dataclasses():
    cfg = load_train_config(
        ["optim.lr=1e-3", "ablation=no_thsc", "model.autocast_dtype=bfloat16", "model.thsc=false"]
    )
    assert cfg.optim.lr == 1e-3 and cfg.ablation == "no_thsc"
    assert cfg.model["autocast_dtype"] == "bfloat16"
    assert model_config(cfg).thsc is False


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["optim.lrr=1"], "optim.lrr"),
        (["optim.iteration=2"], "'optim.iteration'.*did you mean 'optim.iterations'\\?"),
        (["data.colision_path=x"], "did you mean 'data.collision_path'\\?"),
        (["+optim.foo=1"], "keys cannot be added with '\\+'"),
        (["nonsense=1"], "'nonsense': Key 'nonsense' is not in struct \\(keys"),  # nothing close: no guess
        (["optim.lr"], "key=value"),
        (["model.not_a_field=3"], "model.not_a_field"),
    ],
)
def test_unknown_keys_are_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        cfg = load_train_config(overrides)
        model_config(cfg)


@pytest.mark.parametrize(
    "ablation, switches, ssl, tasks",
    [
        (
            "none",
            {"thsc": True, "use_static_encoder": True, "use_general_encoder": True, "encoder": "cnn"},
            True,
            2,
        ),
        ("no_ssl", {"thsc": True, "use_static_encoder": True, "use_general_encoder": True}, False, 2),
        ("no_thsc", {"thsc": False, "use_static_encoder": True, "use_general_encoder": True}, True, 2),
        ("no_de", {"thsc": True}, True, 1),
        ("no_dca", {"thsc": True}, True, 1),
        ("no_fs", {"use_static_encoder": False, "use_general_encoder": True}, True, 2),
        ("no_fg", {"use_static_encoder": True, "use_general_encoder": False}, True, 2),
        (
            "resnet18",
            {"encoder": "resnet18", "use_static_encoder": False, "use_general_encoder": True},
            True,
            2,
        ),
        ("dt", {"thsc": False, "use_static_encoder": False, "use_general_encoder": True}, False, 2),
    ],
)
def test_ablation_switches(ablation, switches, ssl, tasks):
    cfg = load_train_config([f"ablation={ablation}"])
    model = model_config(cfg)
    assert {k: getattr(model, k) for k in switches} == switches
    assert cfg.uses_ssl is ssl
    assert int(cfg.uses_exploration) + int(cfg.uses_collision) == tasks
    assert set(ABLATIONS) == {
        "none",
        "no_ssl",
        "no_thsc",
        "no_de",
        "no_dca",
        "no_fs",
        "no_fg",
        "resnet18",
        "dt",
    }


def _corrupt_schema(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    meta = json.loads((dst / "metadata.json").read_text())
    meta["schema_version"] = 999
    (dst / "metadata.json").write_text(json.dumps(meta))
    return dst


BAD_CONFIGS = [
    (["ablation=no_attention"], ValueError, "unknown ablation 'no_attention'"),
    (
        ["data.exploration_batch_trajs=0"],
        ValueError,
        "data.exploration_batch_trajs must be an integer >= 1, got 0",
    ),
    (["data.ssl_batch_pairs=-4"], ValueError, "data.ssl_batch_pairs must be an integer >= 1, got -4"),
    (["optim.trajectory_chunks=3"], ValueError, "not divisible by optim.trajectory_chunks=3"),
    (["optim.length_groups=0"], ValueError, "optim.length_groups must be an integer >= 1, got 0"),
    (
        ["optim.chunks_by_length=true"],
        ValueError,
        "optim.chunks_by_length=true needs optim.trajectory_chunks > 1",
    ),
    (["data.collision_path=null"], ValueError, "data.collision_path is not set"),
    (["ablation=no_de", "data.collision_path=null"], ValueError, "data.collision_path is not set"),
    (
        ["data.ssl_path=/nonexistent/ssl"],
        FileNotFoundError,
        "data.ssl_path='/nonexistent/ssl' does not exist",
    ),
    (
        ["data.collision_batch_trajs=40"],
        ValueError,
        r"holds 8 trajectories, fewer than one batch of data.collision_batch_trajs=40; "
        r"add data.collision_batch_trajs=8 \(the largest batch size that fits\) or collect more data",
    ),
    (["encoder_training=frozen", "ablation=no_ssl"], ValueError, "nothing would train the encoders"),
    (["encoder_training=sometimes"], ValueError, "encoder_training='sometimes'"),
    (["logger.backend=wandb"], ValueError, "logger.backend='wandb'"),
    (["model.d_head=5"], ValueError, "n_heads \\* d_head"),
    (["data.context_steps=300"], ValueError, "at most 256 steps"),
    (["model.detach_encoders=true"], ValueError, "use encoder_training=frozen"),
    (["optim.iterations=0"], ValueError, "optim.iterations must be an integer >= 1, got 0"),
    (
        ["optim.weight_decay=-1e-4"],
        ValueError,
        "optim.weight_decay must be a finite number >= 0, got -0.0001",
    ),
    (["ssl.tau_base=1.5"], ValueError, r"ssl.tau_base must be a finite number >= 0.5 and <= 1, got 1\.5"),
    # values of the wrong type are named, not left to fail deep inside numpy / torch
    (["seed=abc"], ValueError, "seed='abc': expected int"),
    (["resume=maybe"], ValueError, "resume='maybe': expected bool"),
    (["model.dropout=abc"], ValueError, "model.dropout='abc': expected float"),
    (["optim.clip_grad_norm=abc"], ValueError, "optim.clip_grad_norm='abc': expected float or null"),
    # the model must fit the data: D_e trajectories have up to 11 steps, images are 84 px, actions 2-d
    (
        ["model.max_timestep=6"],
        ValueError,
        "exploration_path: its longest trajectory has 11 steps, .*at least 11",
    ),
    (["model.image_size=64"], ValueError, "images are \\(84, 84, 3\\), but model.image_size=64"),
    (["model.action_dim=3"], ValueError, "actions have 2 dimensions, but model.action_dim=3"),
]


@pytest.mark.parametrize("overrides, error, message", BAD_CONFIGS)
def test_bad_configs_fail_before_training(tiny_config, overrides, error, message):
    output_dir = tiny_config().output_dir
    with pytest.raises(error, match=message):
        build_trainer(tiny_config(*overrides))  # refused while loading the config or building the trainer
    assert not Path(output_dir).exists()  # nothing was written


def _resnet18_step(tiny_config, output_dir, *levers):
    """Metrics and parameter gradients of one training step of the resnet18 ablation (dropout off).

    On one thread: with two, the convolutions' reductions split differently per batch shape and some stem
    gradients move by more than the tolerance below (the test would depend on the suite's thread count)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _resnet18_step_on_this_thread(tiny_config, output_dir, *levers)
    finally:
        torch.set_num_threads(threads)


def _resnet18_step_on_this_thread(tiny_config, output_dir, *levers):
    trainer = build_trainer(
        tiny_config(
            "ablation=resnet18", "model.dropout=0.0", "optim.iterations=1", f"output_dir={output_dir}",
            # few ResNet18 images: windows of 4 steps (a micro-batch of 3 still splits them), 2 pairs
            "data.context_steps=4", "data.collision_batch_trajs=2", "data.ssl_batch_pairs=2", *levers,
        )
    )  # fmt: skip
    assert trainer.model_config.encoder == "resnet18"
    try:
        metrics = trainer.step()
        grads = {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}
    finally:
        trainer.close()
    return metrics, grads


_RESNET18_WITHOUT_LEVERS: dict[str, tuple] = {}
"""The step without levers, computed once for the parametrisations below (same seed, same batches)."""


@pytest.mark.parametrize(
    "overrides",
    [
        ["optim.trajectory_chunks=2"],
        ["model.encoder_micro_batch=4"],
        ["optim.trajectory_chunks=2", "model.encoder_micro_batch=3"],
    ],
)
def test_resnet18_accepts_the_memory_levers(tiny_config, overrides, tmp_path):
    """ResNet18's GroupNorm normalises each image on its own: chunks and micro-batches are the same maths,
    so (dropout off, same seed) one training step gives the loss and the gradient of a step without them."""
    import torch

    metrics, grads = _resnet18_step(tiny_config, tmp_path / "levers", *overrides)
    if "reference" not in _RESNET18_WITHOUT_LEVERS:
        _RESNET18_WITHOUT_LEVERS["reference"] = _resnet18_step(tiny_config, tmp_path / "reference")
    reference, reference_grads = _RESNET18_WITHOUT_LEVERS["reference"]
    for key in ("loss", "loss_dt", "loss_byol"):
        assert math.isfinite(metrics[key]) and metrics[key] == pytest.approx(reference[key], rel=1e-5), key
    assert grads.keys() == reference_grads.keys() and any("general_encoder" in n for n in grads)
    for name, grad in reference_grads.items():
        # float32 sums in another order: equal up to 1e-3 of each tensor's largest entry (ResNet18's stem
        # gradients reach ~20 here; a wrongly weighted chunk would be off by tens of percent)
        scale = float(grad.abs().max())
        torch.testing.assert_close(grads[name], grad, rtol=1e-4, atol=1e-3 * scale + 1e-8)


def test_a_file_as_output_dir_is_refused(tiny_config, tmp_path):
    existing = tmp_path / "afile"
    existing.write_text("keep me")
    with pytest.raises(ValueError, match="is a file; expected a folder"):
        build_trainer(tiny_config(f"output_dir={existing}"))
    assert existing.read_text() == "keep me"


@pytest.mark.parametrize(
    "overrides, fits",
    [
        # one too-large batch: the README's small-scale case (64 D_ca trajectories < 150)
        (["data.collision_batch_trajs=150"], "data.collision_batch_trajs=8"),
        # every too-large batch in one message; with trajectory chunks the fit is a multiple of them
        (
            [
                "data.exploration_batch_trajs=9",
                "data.collision_batch_trajs=12",
                "data.ssl_batch_pairs=20",
                "optim.trajectory_chunks=3",
            ],
            "data.exploration_batch_trajs=6 data.collision_batch_trajs=6 data.ssl_batch_pairs=16",
        ),
    ],
)
def test_a_batch_larger_than_the_data_names_the_key_and_the_value_that_fits(tiny_config, overrides, fits):
    """6 D_e, 8 D_ca trajectories, 16 D_ssl pairs: the message's own suggestion must build the trainer."""
    with pytest.raises(ValueError) as error:
        build_trainer(tiny_config(*overrides))
    message = str(error.value)
    suggested = re.search(r"; add (.*?) \(the largest", message)
    assert suggested is not None and suggested.group(1) == fits, message
    assert message.endswith("or collect more data")
    if "optim.trajectory_chunks=3" in overrides:
        assert "fit and are multiples of optim.trajectory_chunks=3" in message
    trainer = build_trainer(tiny_config(*overrides, *fits.split()))
    assert trainer.iteration == 0


def test_a_dataset_smaller_than_any_valid_batch_says_to_collect_more(tiny_config):
    # 6 D_e trajectories cannot form a batch that is a multiple of 7 chunks
    cfg = tiny_config(
        "data.exploration_batch_trajs=7", "data.collision_batch_trajs=7", "optim.trajectory_chunks=7"
    )
    message = (
        "no value of data.exploration_batch_trajs fits this little data: collect more data or lower optim"
    )
    with pytest.raises(ValueError, match=message):
        build_trainer(cfg)


def test_printable_config_shows_the_resolved_model_and_reads_back(tmp_path):
    cfg = load_train_config(["ablation=dt", "model.d_embed=64", "model.d_head=32"])
    printed = printable_config(cfg)
    assert list(printed).index("resolved_model") == list(printed).index("model") + 1
    assert printed["resolved_model"] == dataclasses.asdict(model_config(cfg))
    resolved = printed["resolved_model"]
    assert (resolved["thsc"], resolved["use_static_encoder"], resolved["use_general_encoder"]) == (
        False,
        False,
        True,
    )
    assert (resolved["d_embed"], resolved["encoder"], resolved["detach_encoders"]) == (64, "cnn", False)

    # the printed YAML is a usable --config FILE: same configuration, no warning
    path = tmp_path / "printed.yaml"
    path.write_text(yaml.safe_dump(printed, sort_keys=False))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_train_config(path=path) == cfg
    # resolved_model is output only: editing it changes nothing, and says so
    with pytest.warns(
        UserWarning, match=r"resolved_model .* is ignored; it differs .* \['thsc', 'use_static_encoder'\]"
    ):
        assert model_config(load_train_config(["ablation=none"], path=path)).thsc
    with pytest.raises(ValueError, match="resolved_model is output of --print-config"):
        load_train_config(["resolved_model.thsc=true"], path=path)


def test_dataset_of_the_wrong_kind_is_refused(tiny_config, datasets):
    cfg = tiny_config(f"data.exploration_path={datasets['ca']}")
    with pytest.raises(ValueError, match="data.exploration_path: .* holds a 'ca' dataset, expected 'e'"):
        build_trainer(cfg)
    assert not Path(cfg.output_dir).exists()


def test_dataset_with_an_unknown_schema_is_refused(tiny_config, datasets, tmp_path):
    broken = _corrupt_schema(datasets["ssl"], tmp_path / "ssl_v999")
    cfg = tiny_config(f"data.ssl_path={broken}")
    with pytest.raises(ValueError, match="data.ssl_path: .*schema_version 999 is not supported"):
        build_trainer(cfg)


def test_a_fresh_run_refuses_a_directory_with_checkpoints(tiny_config):
    from navformer_rl.training import train

    train(tiny_config("optim.iterations=1"))
    with pytest.raises(FileExistsError, match="resume=true"):
        build_trainer(tiny_config("optim.iterations=1"))


def test_tensorboard_without_the_package_is_refused(tiny_config):
    try:
        import tensorboard  # noqa: F401

        pytest.skip("tensorboard is installed here")
    except ImportError:
        pass
    cfg = tiny_config("logger.backend=tensorboard")
    with pytest.raises(ValueError, match="needs the `tensorboard` package"):
        build_trainer(cfg)


def test_cuda_without_a_gpu_is_refused(tiny_config):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(ValueError, match="device=cuda but torch sees no CUDA device"):
        build_trainer(tiny_config("device=cuda"))


def test_training_applies_the_setting_only_when_configured(tiny_config, tmp_path, monkeypatch):
    from navformer_rl.training import run

    # the setting changes the process's malloc for good: record the call instead
    calls = []
    monkeypatch.setattr(run, "keep_freed_memory", lambda: calls.append(True) or True)
    run.build_trainer(tiny_config(f"output_dir={tmp_path / 'off'}", "keep_freed_memory=false")).close()
    assert calls == []
    run.build_trainer(tiny_config(f"output_dir={tmp_path / 'on'}")).close()
    assert calls == [True]


@pytest.mark.parametrize("keep, releases", [(True, 2), (False, 0)])
def test_training_releases_the_kept_memory_at_every_checkpoint(
    tiny_config, tmp_path, monkeypatch, keep, releases
):
    from navformer_rl.training import run

    calls = []
    monkeypatch.setattr(run, "keep_freed_memory", lambda: True)
    monkeypatch.setattr(run, "release_free_memory", lambda: calls.append(True) or True)
    run.train(
        tiny_config(
            "optim.iterations=4", "checkpoint.interval=2", f"keep_freed_memory={str(keep).lower()}",
            f"output_dir={tmp_path / 'run'}",
        )
    )  # fmt: skip
    assert len(calls) == releases  # after the checkpoints at iterations 2 and 4


def test_data_subset_keys_keep_the_first_items(tiny_config):
    from navformer_rl.training.datasets import open_datasets

    datasets = open_datasets(
        tiny_config("data.exploration_trajectories=3", "data.collision_trajectories=4", "data.ssl_pairs=5")
    )
    assert datasets["e"].num_trajectories == 3 and datasets["ca"].num_trajectories == 4
    assert len(datasets["ssl"]) == 5
    with pytest.raises(
        ValueError, match=r"data.exploration_trajectories=7: expected null or an integer in \[1, 6\]"
    ):
        open_datasets(tiny_config("data.exploration_trajectories=7"))
