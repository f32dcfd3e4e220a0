"""Shipped weights: ``pretrained:NAME`` resolution with sha256 checks, model cards from measured fields, and a
tiny end-to-end evaluation and validation of a shipped checkpoint."""

from __future__ import annotations

import csv
import json
import shutil

import pytest
import torch
from safetensors.torch import load_file

from navformer_rl.cli import main
from navformer_rl.evaluation.episodes import Setup, make_episode_set, save_episode_set
from navformer_rl.evaluation.tables import format_ratio, format_sr
from navformer_rl.pretrained import (
    PRETRAINED_DIR_ENV,
    load_pretrained,
    load_pretrained_policy,
    read_registry,
    shipped_names,
)
from navformer_rl.pretrained.export import write_pretrained
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training import load_train_config, train
from navformer_rl.training.pretrained_registry import PACKAGED_ROOT, file_sha256, resolve_pretrained

from .conftest import TINY_OVERRIDES, data_overrides


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, datasets):
    """A finished 2-iteration tiny run with checkpoints at 1 and 2 (log_interval 1: one iteration_s row per
    iteration)."""
    out = tmp_path_factory.mktemp("pretrained") / "run"
    cfg = load_train_config(
        [
            *data_overrides(datasets),
            *TINY_OVERRIDES,
            f"output_dir={out}",
            "optim.iterations=2",
            "checkpoint.interval=1",
            "seed=7",
        ]
    )
    return train(cfg)


@pytest.fixture(scope="module")
def shipped(trained_run, tmp_path_factory):
    """The run shipped as ``pretrained:navformer`` into a fresh pretrained root (no card, no evaluation)."""
    root = tmp_path_factory.mktemp("pretrained_root")
    write_pretrained(trained_run.run_dir, "navformer", out_dir=root)
    return root


@pytest.fixture(scope="module")
def shipped_evaluation(shipped, tmp_path_factory):
    """``navformer evaluate --checkpoint pretrained:navformer`` on one tiny episode: its output folder."""
    work = tmp_path_factory.mktemp("shipped_eval")
    episodes = make_episode_set(
        [Setup("7.5m-2r", 7.5, ("jackal", "jackal"), (True, True))], 1, 1, seed=1, name="one", max_steps=6
    )
    save_episode_set(episodes, work / "episodes.json")
    out = work / "eval"
    argv = ["evaluate", "--method", "navformer", "--checkpoint", "pretrained:navformer", "--episodes",
            str(work / "episodes.json"), "--out", str(out), "--videos", "0", "--maps", "0",
            "--no-progress"]  # fmt: skip
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(PRETRAINED_DIR_ENV, str(shipped))
        assert main(argv) == 0
    return out


def test_the_packaged_weights_check_out_and_load(monkeypatch):
    """Every name the package ships resolves (each file's sha256 checked) and loads as its method's model."""
    monkeypatch.delenv(PRETRAINED_DIR_ENV, raising=False)
    registry = read_registry(PACKAGED_ROOT)
    assert "navformer" in registry
    for name, entry in registry.items():
        assert resolve_pretrained(name) == PACKAGED_ROOT / name
        model, config = load_pretrained(name)
        assert not model.training and (config.thsc == (entry["method"] == "navformer"))
        assert (PACKAGED_ROOT / name / "MODEL_CARD.md").is_file()


def test_pretrained_names_resolve_to_the_exact_weights(shipped, trained_run, monkeypatch):
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(shipped))
    folder = ckpt.resolve_checkpoint("pretrained:navformer")
    assert folder == shipped / "navformer"
    assert shipped_names() == ("navformer",)
    source = trained_run.checkpoint
    for name in (ckpt.CONFIG_FILENAME, ckpt.WEIGHTS_FILENAME):  # byte for byte, float32 kept
        assert (folder / name).read_bytes() == (source / name).read_bytes()
    entry = read_registry(shipped)["navformer"]
    assert entry == {
        "method": "navformer",
        "files": {name: file_sha256(source / name) for name in (ckpt.CONFIG_FILENAME, ckpt.WEIGHTS_FILENAME)},
    }
    assert ckpt.read_checkpoint_config("pretrained:navformer")["iteration"] == 2
    saved = load_file(str(source / ckpt.WEIGHTS_FILENAME))
    model, config = load_pretrained("navformer")
    assert config.d_embed == 16 and not model.training
    assert all(torch.equal(model.state_dict()[key], saved[key]) for key in saved)
    policy = load_pretrained_policy("pretrained:navformer", native=False)
    assert policy.native is False
    assert all(torch.equal(policy.model.state_dict()[key], saved[key]) for key in saved)
    from navformer_rl.modules import NavFormerPolicy

    by_name = load_pretrained_policy("navformer", native=False)
    assert isinstance(by_name, NavFormerPolicy) and by_name.native is False
    assert all(torch.equal(by_name.model.state_dict()[key], saved[key]) for key in saved)


def test_weights_trained_on_short_windows_load_attending_to_them(trained_run, tmp_path, monkeypatch):
    """Shipped weights trained with ``data.context_steps=W`` load attending to their last W steps (by the
    short or the ``pretrained:`` name); a ``context_steps`` option overrides it (None: the whole context)."""
    source = tmp_path / "windowed"
    shutil.copytree(trained_run.checkpoint, source)
    header = json.loads((source / ckpt.CONFIG_FILENAME).read_text())
    header["train_config"]["data"]["context_steps"] = 4
    (source / ckpt.CONFIG_FILENAME).write_text(json.dumps(header))
    root = tmp_path / "root"
    write_pretrained(source, "navformer_w4", out_dir=root)
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(root))
    assert load_pretrained_policy("navformer_w4").context_steps == 4
    assert load_pretrained_policy("pretrained:navformer_w4").context_steps == 4
    assert load_pretrained_policy("navformer_w4", context_steps=8).context_steps == 8
    assert load_pretrained_policy("navformer_w4", context_steps=None).context_steps is None
    card = (root / "navformer_w4" / "MODEL_CARD.md").read_text()
    assert (
        "| trajectory windows | 4 steps (data.context_steps); the policy attends to as many at evaluation |"
        in card
    )


def test_a_corrupt_shipped_file_is_refused_naming_it(shipped, datasets, tmp_path, monkeypatch, capsys):
    root = tmp_path / "root"
    shutil.copytree(shipped, root)
    weights = root / "navformer" / ckpt.WEIGHTS_FILENAME
    data = bytearray(weights.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit of one float
    weights.write_bytes(bytes(data))
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(root))
    with pytest.raises(
        ValueError, match=rf"{weights} is corrupt: .*records .* for pretrained:navformer; restore"
    ):
        ckpt.load_policy_model("pretrained:navformer")
    argv = ["validate", "--checkpoint", "pretrained:navformer", "--exploration", str(datasets["e"])]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"navformer validate: error: {weights} is corrupt")


def test_unknown_and_missing_names_are_refused_clearly(shipped, tmp_path, monkeypatch):
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(shipped))
    with pytest.raises(
        ValueError, match=r"'pretrained:nope' is not shipped .*: the shipped names are navformer \(registry "
    ):
        ckpt.resolve_checkpoint("pretrained:nope")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(
        ValueError, match=r"'pretrained:navformer' is not shipped in this installation: none are \(registry "
    ):
        resolve_pretrained("pretrained:navformer", empty)
    root = tmp_path / "root"
    shutil.copytree(shipped, root)
    (root / "navformer" / ckpt.WEIGHTS_FILENAME).unlink()
    with pytest.raises(FileNotFoundError,
                       match=r"^pretrained:navformer is not shipped in this installation: .*"
                       rf"{ckpt.WEIGHTS_FILENAME} is missing"):  # fmt: skip
        load_pretrained("navformer", root)
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(tmp_path / "absent"))
    with pytest.raises(NotADirectoryError, match=f"is not a folder .*{PRETRAINED_DIR_ENV}"):
        load_pretrained_policy("navformer")


def test_a_shipped_checkpoint_evaluates_end_to_end(shipped, shipped_evaluation):
    run = json.loads((shipped_evaluation / "run.json").read_text())
    assert run["checkpoint"] == str(shipped / "navformer")
    assert run["checkpoint_sha256"] == read_registry(shipped)["navformer"]["files"][ckpt.WEIGHTS_FILENAME]
    assert len((shipped_evaluation / "episodes.jsonl").read_text().splitlines()) == 2  # 2 measured robots


def test_a_shipped_checkpoint_validates_as_its_run(shipped, trained_run, datasets, monkeypatch):
    from navformer_rl.training.validation import score_checkpoints

    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(shipped))
    sets = {"e": str(datasets["e"])}
    (shipped_row,) = score_checkpoints(["pretrained:navformer"], sets, batch_trajs=2)
    (run_row,) = score_checkpoints([str(trained_run.run_dir)], sets, batch_trajs=2)
    assert shipped_row["iteration"] == 2
    assert shipped_row["loss_dt_exploration"] == run_row["loss_dt_exploration"]


def test_the_model_card_holds_the_measured_fields(
    trained_run, shipped, shipped_evaluation, tmp_path, monkeypatch, capsys
):
    card = {"hardware": "2-core CPU (test)", "failure_modes": ["circles near walls"], "summary": "Tiny."}
    (tmp_path / "card.json").write_text(json.dumps(card))
    root = tmp_path / "root"
    argv = ["pretrained", "export", "--checkpoint", str(trained_run.run_dir), "--name", "navformer",
            "--evaluation", str(shipped_evaluation), "--card", str(tmp_path / "card.json"),
            "--out", str(root)]  # fmt: skip
    assert main(argv) == 0
    text = (root / "navformer" / "MODEL_CARD.md").read_text()
    log = trained_run.run_dir / "logs" / "navformer" / "scalars" / "iteration_s.csv"
    seconds = sum(float(value) for _, value in csv.reader(log.read_text().splitlines()))  # log_interval 1
    weights_sha = read_registry(root)["navformer"]["files"][ckpt.WEIGHTS_FILENAME]
    (row,) = [
        r for r in csv.DictReader((shipped_evaluation / "summary.csv").open()) if r["setup"] == "7.5m-2r"
    ]
    sr = format_sr(float(row["sr"]), (float(row["sr_low"] or "nan"), float(row["sr_high"] or "nan")))
    cr = format_ratio(float(row["cr"]), (float(row["cr_low"] or "nan"), float(row["cr_high"] or "nan")))
    for expected in (
        "# `pretrained:navformer`: NavFormer\n\nTiny.\n",
        f"`{weights_sha}`",
        f"exported from `{trained_run.checkpoint}`",
        "| iterations | 2 (of optim.iterations=2) |",
        "| seed | 7 |",
        "| batches | 2 D_e trajectories, 4 D_ca trajectories, 4 D_ssl pairs |",
        "| model | encoder=cnn, use_static_encoder=True, use_general_encoder=True, thsc=True, d_embed=16, "
        "n_blocks=1, n_heads=2, context_tokens=1024 (every field: config.json) |",
        "6 of its 6 trajectories used (collection seed 11)",
        "8 of its 8 trajectories used (collection seed 12)",
        "16 of its 16 pairs used (collection seed 13)",
        "| hardware | 2-core CPU (test) |",
        f"| training time | {seconds:.0f} s ({seconds / 3600:.2f} h): the summed iteration times of `{log}`",
        "### navformer on `one`",
        "1 episodes of at most 6 steps",
        f"| 7.5m-2r | 1 | 2 | {sr} | ",
        f" | {cr} |",
        "## Known failure modes\n\n- circles near walls\n",
    ):
        assert expected in text, expected
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(root))
    assert main(["pretrained", "list"]) == 0
    assert "| pretrained:navformer | navformer | ok |" in capsys.readouterr().out


def test_export_refuses_other_weights_evaluations_bad_fields_and_overwrites(
    trained_run, shipped, shipped_evaluation, tmp_path
):
    earlier = trained_run.run_dir / "checkpoints" / "iter_000001"
    with pytest.raises(ValueError, match=f"{shipped_evaluation} evaluated other weights"):
        write_pretrained(earlier, "navformer", evaluations=[shipped_evaluation], out_dir=tmp_path)
    with pytest.raises(ValueError, match="card field 'results' is not one of summary, hardware"):
        write_pretrained(earlier, "navformer", card={"results": "99 %"}, out_dir=tmp_path)
    with pytest.raises(ValueError, match="card field 'failure_modes': expected a list of strings"):
        write_pretrained(earlier, "navformer", card={"failure_modes": "walls"}, out_dir=tmp_path)
    with pytest.raises(ValueError, match="pretrained name 'Nav Former'"):
        write_pretrained(earlier, "Nav Former", out_dir=tmp_path)
    with pytest.raises(FileExistsError, match="pretrained:navformer.*already exists"):
        write_pretrained(earlier, "navformer", out_dir=shipped)
    assert not list(tmp_path.iterdir())  # nothing written by the refused exports
    card = write_pretrained(earlier, "navformer", out_dir=tmp_path) / "MODEL_CARD.md"
    text = card.read_text()
    assert "| iterations | 1 (of optim.iterations=2) |" in text
    assert "No evaluation was exported with these weights." in text and "None recorded." in text


def test_the_evaluation_recipe_takes_a_pretrained_name(shipped, monkeypatch):
    """``checkpoint=pretrained:NAME`` as a hydra override reaches the recipe's policy check intact."""
    import importlib.util
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    recipe = Path(__file__).resolve().parents[2] / "recipes" / "evaluate"
    spec = importlib.util.spec_from_file_location("evaluate_recipe_utils", recipe / "utils.py")
    utils = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(utils)
    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(shipped))
    with initialize_config_dir(config_dir=str(recipe), version_base="1.3"):
        cfg = compose("config", ["method=navformer", "checkpoint=pretrained:navformer"])
        unknown = compose("config", ["method=dt", "checkpoint=pretrained:dt"])
    assert cfg.checkpoint == "pretrained:navformer"
    utils.check_policy(cfg)  # loads and checks the shipped weights
    with pytest.raises(ValueError, match="'pretrained:dt' is not shipped .*the shipped names are navformer"):
        utils.check_policy(unknown)


def test_the_demo_evaluates_the_shipped_navformer_beside_its_own_models(shipped, tmp_path, monkeypatch):
    """Stage 3 of the demo adds ``pretrained:navformer`` on the same episodes;
    a name not shipped is skipped."""
    from navformer_rl.demo import pipeline
    from navformer_rl.demo.config import DemoConfig

    monkeypatch.setenv(PRETRAINED_DIR_ENV, str(shipped))
    cfg = DemoConfig.preset(
        "quick", out_dir=tmp_path, methods=("vrw",), shipped=("navformer", "dt"), trials_per_setup=1,
        trials_per_world=1, max_steps=6, videos_per_setup=0, workers=1,
    )  # fmt: skip
    assert pipeline.shipped_weights(cfg) == {"navformer": "navformer"}
    folders = pipeline.evaluate_stage(cfg, {}, progress=False)
    assert [folder.name for folder in folders] == ["vrw", "pretrained_navformer"]
    run = json.loads((folders[1] / "run.json").read_text())
    assert run["label"] == "pretrained:navformer"
    assert run["checkpoint"] == str(shipped / "navformer")
    same_episodes = [
        sorted(
            json.loads(line)["episode_id"] for line in (folder / "episodes.jsonl").read_text().splitlines()
        )
        for folder in folders
    ]
    assert same_episodes[0] == same_episodes[1]
    with pytest.raises(ValueError, match="pretrained name 'Bad Name'"):
        DemoConfig(shipped=("Bad Name",)).validate()


def test_the_card_counts_a_list_of_dataset_folders_as_one(datasets):
    """A run trained on ``data.exploration_path=[a, b]`` gets a card row with the summed items."""
    from navformer_rl.pretrained.card import _datasets_items

    items, seed = _datasets_items([str(datasets["e"])])
    assert items >= 1
    assert _datasets_items([str(datasets["e"]), str(datasets["e"])]) == (2 * items, seed)
    assert _datasets_items([str(datasets["e"]), str(datasets["e"] / "absent")]) == (None, None)  # unknown


def test_the_card_names_an_evaluation_that_ran_on_a_shorter_context():
    from navformer_rl.pretrained.card import _results_markdown

    run = {"label": "navformer_w16", "episode_set": {"name": "table1", "episodes": 540, "max_steps": 500},
           "seed": 0, "device": "cpu", "transformer_step": "native", "confidence": 0.95,
           "cluster": "trial"}  # fmt: skip
    whole = "\n".join(_results_markdown({"run": run, "folder": "f", "rows": []}))
    short = "\n".join(_results_markdown({"run": {**run, "context_steps": 16}, "folder": "f", "rows": []}))
    assert "(native transformer step), " in whole and "attending" not in whole
    assert "(native transformer step, attending to its last 16 steps), " in short
