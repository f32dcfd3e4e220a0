"""Fine-tuning: ``init_from=`` starts at a source checkpoint's weights with fresh optimisers and schedules;
the three source forms, the model check, the record in the run files, and resume winning over
``init_from``."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.cli import main
from navformer_rl.pretrained import PRETRAINED_DIR_ENV
from navformer_rl.pretrained.export import write_pretrained
from navformer_rl.training import build_trainer, load_train_config, train
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.pretrained_registry import file_sha256

from .conftest import TINY_OVERRIDES, data_overrides


@pytest.fixture(scope="module")
def source(tmp_path_factory, datasets):
    """A finished 2-iteration tiny run (checkpoints at 1 and 2), also shipped as ``pretrained:navformer`` in a
    temporary registry: ``(run directory, pretrained root)``."""
    out = tmp_path_factory.mktemp("init_from_source")
    cfg = load_train_config(
        [
            *data_overrides(datasets),
            *TINY_OVERRIDES,
            f"output_dir={out / 'run'}",
            "optim.iterations=2",
            "checkpoint.interval=1",
            "checkpoint.keep_last=0",
            "seed=5",
        ]  # fmt: skip
    )
    run_dir = train(cfg).run_dir
    write_pretrained(run_dir, "navformer", out_dir=out / "pretrained")
    return run_dir, out / "pretrained"


@pytest.mark.parametrize(
    "form, folder, extra",
    [
        ("{run}", "iter_000002", []),
        ("{run}/checkpoints/iter_000001", "iter_000001", ["model.dropout=0.0"]),  # dropout may differ
        ("pretrained:navformer", "iter_000002", ["encoder_training=frozen"]),  # so may the encoder mode
    ],
    ids=["run-directory", "checkpoint-folder", "pretrained-name"],
)
def test_a_fine_tuning_run_starts_at_the_source_weights_with_fresh_optimisers(
    source, tiny_config, monkeypatch, form, folder, extra
):
    run_dir, root = source
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(root))
    designation = form.format(run=run_dir)
    trainer = build_trainer(tiny_config(f"init_from={designation}", *extra))
    source_weights = load_file(str(run_dir / "checkpoints" / folder / ckpt.WEIGHTS_FILENAME))
    state = trainer.model.state_dict()
    assert state.keys() == source_weights.keys()
    assert all(torch.equal(state[key], source_weights[key]) for key in state)
    # fresh: no optimiser state, iteration 0, tau schedule and samplers at their start
    assert all(not optimizer.state for optimizer in trainer.optimizers.values())
    assert trainer.iteration == 0 and trainer.tau_schedule.step_count == 0
    assert trainer.cross_task.iteration == 0
    # BYOL's EMA target starts as a copy of the loaded encoders
    target = trainer.byol_loss.target_online_network_params
    for name, value in trainer.model.dve.static_encoder.state_dict().items():
        assert torch.equal(target[("static", "encoder", *name.split("."))], value), name
    recorded = trainer.run_info["init_from"]
    expected_folder = (
        (root / "navformer") if form.startswith("pretrained:") else run_dir / "checkpoints" / folder
    )
    assert recorded == {
        "checkpoint": designation,
        "folder": str(expected_folder.resolve()),
        "iteration": int(folder[-1]),
        "weights_sha256": file_sha256(expected_folder / ckpt.WEIGHTS_FILENAME),
    }


def test_the_run_records_its_source_and_resume_wins_over_init_from(source, tiny_config, tmp_path):
    run_dir, _ = source
    out = tmp_path / "finetuned"
    first = train(tiny_config(f"init_from={run_dir}", "optim.iterations=1", f"output_dir={out}"))
    assert first.iterations == 1
    recorded = json.loads((out / "train_config.json").read_text())
    identity = recorded["run"]["init_from"]
    assert recorded["init_from"] == str(run_dir) and identity["iteration"] == 2
    assert recorded["run"]["world_size"] == 1
    # a shipped fine-tuned run's model card names the weights it started from
    write_pretrained(out, "navformer", out_dir=tmp_path / "shipped")
    card = (tmp_path / "shipped" / "navformer" / "MODEL_CARD.md").read_text()
    assert (
        f"| initialised from | `{run_dir}`: iteration 2 of `{identity['folder']}` (weights sha256 "
        f"`{identity['weights_sha256'][:16]}...`); fine-tuned with fresh optimisers" in card
    )
    assert ckpt.read_checkpoint_config(out)["run"]["init_from"] == identity
    assert load_train_config(["output_dir=x"], out / "train_config.json").init_from == str(
        run_dir
    )  # reads back
    other = run_dir / "checkpoints" / "iter_000001"
    with pytest.warns(UserWarning, match=f"init_from={other} is ignored: resuming .*iter_000001"):
        resumed = train(
            tiny_config(f"init_from={other}", "optim.iterations=2", f"output_dir={out}", "resume=true")
        )
    assert resumed.iterations == 2
    again = json.loads((out / "train_config.json").read_text())
    assert again["init_from"] == str(run_dir) and again["run"]["init_from"] == identity


def test_a_source_of_another_model_is_refused_in_one_line(
    source, tiny_config, base_overrides, tmp_path, capsys
):
    run_dir, _ = source
    with pytest.raises(
        ValueError,
        match=(
            r"^init_from=.*: the checkpoint's model differs from the configured one in "
            r"d_embed \(checkpoint 16, "
            r"configured 32\), d_head \(checkpoint 8, configured 16\); set ablation= / model.<key>= to"
        ),
    ):
        build_trainer(tiny_config(f"init_from={run_dir}", "model.d_embed=32", "model.d_head=16"))
    with pytest.raises(ValueError, match=r"init_from=.*differs .* in use_static_encoder \(checkpoint True"):
        build_trainer(tiny_config(f"init_from={run_dir}", "ablation=dt"))
    argv = [
        "train",
        *base_overrides,
        f"output_dir={tmp_path / 'out'}",
        f"init_from={run_dir}",
        "model.n_blocks=2",
    ]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert (
        line.startswith("navformer train: error: init_from=")
        and "n_blocks (checkpoint 1, configured 2)" in line
    )
    assert not (tmp_path / "out").exists()  # refused before anything was written
    with pytest.raises(FileNotFoundError, match=rf"^init_from={tmp_path}/nope: no checkpoint at"):
        build_trainer(tiny_config(f"init_from={tmp_path}/nope"))
    with pytest.raises(ValueError, match=r"init_from='  ': expected null, a run directory"):
        build_trainer(tiny_config("init_from='  '"))
