"""NavFormer / DT from checkpoints, FCA, and clear errors for bad inputs."""

import dataclasses
import json
import shutil

import pytest
import torch

from navformer_rl.evaluation.episodes import save_episode_set
from navformer_rl.evaluation.harness import (
    METHODS,
    EvaluateConfig,
    PolicySpec,
    checkpoint_ablation,
    evaluate,
)
from navformer_rl.modules import NavFormerConfig


def test_evaluate_takes_an_evaluate_config_and_its_fields_as_keywords(tmp_path, tiny_episodes):
    """Keywords replace the config's fields; a name that is not a field is refused before anything runs."""
    config = EvaluateConfig(maps_per_setup=0, videos_per_setup=0, progress=False, label="walk")
    result = evaluate("vrw", tiny_episodes, tmp_path / "vrw", config, seed=3)
    run = json.loads((tmp_path / "vrw" / "run.json").read_text())
    assert (run["label"], run["seed"]) == ("walk", 3) and len(result.records) == 4
    assert {f.name for f in dataclasses.fields(EvaluateConfig)} >= {"checkpoint", "workers", "context_steps"}
    with pytest.raises(TypeError, match="maps"):
        evaluate("vrw", tiny_episodes, tmp_path / "other", config, maps=1)
    assert not (tmp_path / "other").exists()


@pytest.mark.parametrize("method", ["navformer", "dt"])
def test_checkpoint_methods_run_every_robot(tmp_path, tiny_episodes, checkpoints, method):
    result = evaluate(
        method, tiny_episodes, tmp_path / method, checkpoint=checkpoints[method],
        maps_per_setup=0, videos_per_setup=0, progress=False,
    )  # fmt: skip
    assert len(result.records) == 4
    # An untrained model still drives: every robot moved.
    assert all(r.path_length > 0 for r in result.records)
    run = json.loads((tmp_path / method / "run.json").read_text())
    assert run["model_config"]["thsc"] is (method == "navformer")
    assert run["ablation"] is None  # the fixture's checkpoints record no training configuration


def test_a_run_directory_is_resolved_once(tmp_path, tiny_episodes, checkpoint_factory, monkeypatch):
    """A run that is still training saves a newer checkpoint after the evaluation checked the one it named:
    the evaluation keeps driving (and reporting) the checkpoint it checked."""
    from navformer_rl.modules import NavFormerModel
    from navformer_rl.training.checkpoint import save_checkpoint

    run_dir = checkpoint_factory(tmp_path / "run", NavFormerConfig())
    validate = PolicySpec.validate

    def validate_then_train_on(self, label=None):
        description = validate(self, label)
        model = NavFormerModel(NavFormerConfig())  # other weights (not seeded like the first)
        save_checkpoint(
            run_dir, 2, model_state=model.state_dict(), model_config=dataclasses.asdict(NavFormerConfig()),
            train_config={}, resume_state=None,
        )  # fmt: skip
        return description

    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    monkeypatch.setattr(PolicySpec, "validate", validate_then_train_on)
    raced = evaluate("navformer", tiny_episodes, tmp_path / "raced", checkpoint=run_dir, **kwargs)
    monkeypatch.undo()
    first = evaluate(
        "navformer", tiny_episodes, tmp_path / "first",
        checkpoint=run_dir / "checkpoints" / "iter_000001", **kwargs,
    )  # fmt: skip
    run = json.loads((tmp_path / "raced" / "run.json").read_text())
    assert run["checkpoint"].endswith("iter_000001")
    assert [r.to_dict() for r in raced.records] == [r.to_dict() for r in first.records]


def test_a_label_naming_an_ablation_must_be_the_checkpoints(tmp_path, tiny_episodes, checkpoint_factory):
    """`--label navformer-no_thsc` on a full model would be compared with Table IV's w/o THSC row."""
    make_checkpoint = checkpoint_factory
    full = make_checkpoint(tmp_path / "full", NavFormerConfig(), {"ablation": "none"})
    out = tmp_path / "out"
    named = {
        "navformer-no_thsc": "no_thsc",
        "navformer-no_ssl": "no_ssl",
        "NavFormer_resnet18-s1": "resnet18",
    }
    for label, ablation in named.items():
        with pytest.raises(
            ValueError, match=f"names the training ablation '{ablation}'.*trained with ablation=none"
        ):
            evaluate("navformer", tiny_episodes, out, checkpoint=full, label=label, progress=False)
    assert not out.exists()  # refused before anything was written or run
    # labels that name no ablation stay free; the checkpoint's ablation is recorded
    for label in (None, "navformer-seed1", "navformer-none"):
        assert PolicySpec("navformer", str(full)).validate(label)["ablation"] == "none"
    # the matching ablation is accepted
    no_thsc = make_checkpoint(tmp_path / "no_thsc", NavFormerConfig(thsc=False), {"ablation": "no_thsc"})
    assert PolicySpec("navformer", str(no_thsc)).validate("navformer-no_thsc")["ablation"] == "no_thsc"
    # a DT checkpoint, or a method without a checkpoint, is no NavFormer ablation either
    dt = make_checkpoint(tmp_path / "dt", NavFormerConfig.dt_baseline(), {"ablation": "dt"})
    with pytest.raises(ValueError, match="names the method 'navformer'.*evaluated method is 'dt'"):
        evaluate("dt", tiny_episodes, out, checkpoint=dt, label="navformer-no_thsc", progress=False)
    with pytest.raises(ValueError, match="names the method 'navformer'.*evaluated method is 'vrw'"):
        evaluate("vrw", tiny_episodes, out, label="navformer-no_thsc", progress=False)
    assert not out.exists()


def test_without_a_recorded_ablation_the_architecture_is_checked(tmp_path, checkpoints):
    # the fixtures' checkpoints record no training config (written by hand): the architecture decides
    assert (
        PolicySpec("navformer", str(checkpoints["navformer"])).validate("navformer-seed1")["ablation"] is None
    )
    with pytest.raises(ValueError, match=r"records no training ablation.*'thsc': \(True, False\)"):
        PolicySpec("navformer", str(checkpoints["navformer"])).validate("navformer-no_thsc")
    # no_ssl only changes the training data: the full architecture is all that can be checked
    PolicySpec("navformer", str(checkpoints["navformer"])).validate("navformer-no_ssl")
    # the run directory's train_config.json is read when the checkpoint header has no training config
    run = shutil.copytree(checkpoints["navformer"], tmp_path / "run")
    (run / "train_config.json").write_text(json.dumps({"ablation": "none"}))
    assert checkpoint_ablation(run) == "none"
    with pytest.raises(ValueError, match="trained with ablation=none"):
        PolicySpec("navformer", str(run)).validate("navformer-no_ssl")


def test_wrong_checkpoint_kind_is_refused(tmp_path, tiny_episodes, checkpoints):
    with pytest.raises(ValueError, match="--method navformer"):
        evaluate("dt", tiny_episodes, tmp_path / "x", checkpoint=checkpoints["navformer"], progress=False)
    with pytest.raises(ValueError, match="--method dt"):
        evaluate("navformer", tiny_episodes, tmp_path / "x", checkpoint=checkpoints["dt"], progress=False)


def test_foreign_and_missing_checkpoints(tmp_path, tiny_episodes):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "config.json").write_text(json.dumps({"format": "someone-else/3"}))
    (foreign / "model.safetensors").write_bytes(b"not a tensor file")
    with pytest.raises(ValueError, match="format"):
        evaluate("navformer", tiny_episodes, tmp_path / "x", checkpoint=foreign, progress=False)
    with pytest.raises(FileNotFoundError):
        evaluate("navformer", tiny_episodes, tmp_path / "x", checkpoint=tmp_path / "nothing", progress=False)
    with pytest.raises(ValueError, match="needs a checkpoint"):
        evaluate("navformer", tiny_episodes, tmp_path / "x", progress=False)
    with pytest.raises(ValueError, match="takes no checkpoint"):
        evaluate("vrw", tiny_episodes, tmp_path / "x", checkpoint=foreign, progress=False)


def test_corrupt_checkpoints_name_the_file(tmp_path, tiny_episodes, checkpoints):
    import shutil

    from navformer_rl.training.checkpoint import resolve_checkpoint

    def broken(name, config=None, weights=None):
        folder = tmp_path / name
        shutil.copytree(resolve_checkpoint(checkpoints["navformer"]), folder)
        if config is not None:
            (folder / "config.json").write_text(config)
        if weights is not None:
            path = folder / "model.safetensors"
            path.write_bytes(path.read_bytes()[:weights])
        return folder

    cases = [
        (broken("truncated", weights=1000), r"model\.safetensors cannot be read as safetensors"),
        (broken("not_json", config="{oops"), r"config\.json is not valid JSON"),
        (broken("a_list", config="[1, 2]"), r"config\.json: expected a JSON object, got list"),
    ]
    for folder, message in cases:
        with pytest.raises(ValueError, match=message):
            evaluate("navformer", tiny_episodes, tmp_path / "x", checkpoint=folder, progress=False)


def test_unknown_method_lists_the_valid_ones(tmp_path, tiny_episodes):
    with pytest.raises(
        ValueError,
        match="unknown method 'a3c'; expected one of navformer, dt, vrw, fca, dsac, matdn, frontier",
    ):
        evaluate("a3c", tiny_episodes, tmp_path / "x", progress=False)
    assert METHODS == ("navformer", "dt", "vrw", "fca", "dsac", "matdn", "frontier")


def test_bad_episode_file_and_worker_count(tmp_path, tiny_episodes):
    path = save_episode_set(tiny_episodes, tmp_path / "set.json")
    path.write_text(path.read_text().replace('"trial": 1', '"trial": 7'))
    with pytest.raises(ValueError, match="corrupt or was edited"):
        evaluate("vrw", path, tmp_path / "x", progress=False)
    with pytest.raises(ValueError, match="workers"):
        evaluate("vrw", tiny_episodes, tmp_path / "x", workers=0, progress=False)
    # refused before any episode runs (nothing written), not after the last one
    with pytest.raises(ValueError, match="confidence=1.0"):
        evaluate("vrw", tiny_episodes, tmp_path / "y", confidence=1.0, progress=False)
    with pytest.raises(ValueError, match="video_fps=0"):
        evaluate("vrw", tiny_episodes, tmp_path / "y", video_fps=0, progress=False)
    assert not (tmp_path / "y").exists()


def test_fca_reaches_targets(tmp_path, tiny_episodes):
    """The privileged upper bound finds both targets of the first tiny episode within 80 steps."""
    episodes = dataclasses.replace(tiny_episodes, episodes=tiny_episodes.episodes[:1], max_steps=80)
    result = evaluate("fca", episodes, tmp_path / "fca", maps_per_setup=0, videos_per_setup=0, progress=False)
    assert all(r.success for r in result.records)
    assert all(r.steps == r.success_step for r in result.records)
    assert result.summaries[0].metrics.sr == 1.0


def test_the_exploration_expert_finds_its_targets_without_knowing_where_they_are(tmp_path, tiny_episodes):
    """The D_e expert, closed-loop on the evaluation's episodes: both robots of the first tiny episode find
    their target within 80 steps; it is reset on every episode's world (bind), so a second run repeats it."""
    episodes = dataclasses.replace(tiny_episodes, episodes=tiny_episodes.episodes[:1], max_steps=80)
    first = evaluate(
        "frontier", episodes, tmp_path / "a", maps_per_setup=0, videos_per_setup=0, progress=False
    )
    again = evaluate(
        "frontier", episodes, tmp_path / "b", maps_per_setup=0, videos_per_setup=0, progress=False
    )
    assert all(r.success for r in first.records)
    assert [r.success_step for r in first.records] == [r.success_step for r in again.records]


def test_an_expert_policy_refuses_to_act_before_it_is_bound():
    from tensordict import TensorDict

    from navformer_rl.baselines import FrontierPolicy

    td = TensorDict({("agents", "done"): torch.zeros(2, 1, dtype=torch.bool)})
    with pytest.raises(RuntimeError, match="FrontierPolicy is privileged: call bind"):
        FrontierPolicy()(td)


def test_another_methods_results_are_not_overwritten(tmp_path, tiny_episodes):
    out = tmp_path / "shared"
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    rows = (out / "episodes.jsonl").read_text()
    with pytest.raises(
        FileExistsError, match="holds the results of 'vrw'; evaluating 'fca' there would replace"
    ):
        evaluate("fca", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    assert (out / "episodes.jsonl").read_text() == rows


def test_an_error_raised_while_handling_ctrl_c_still_reports_an_interrupt():
    # tensordict's to_module exit turns a KeyboardInterrupt into a RuntimeError; the CLI must see through it
    from navformer_rl.cli.main import _interrupted

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise RuntimeError("Converting a tensordict to boolean value is not permitted") from None
    except RuntimeError as error:
        assert _interrupted(error)
    assert not _interrupted(RuntimeError("a real error"))


def test_episode_ids_that_would_share_a_result_file_are_refused(tmp_path, tiny_episodes):
    first, second = tiny_episodes.episodes
    twice = dataclasses.replace(tiny_episodes, episodes=(first, first))
    with pytest.raises(ValueError, match="episode id '7.5m-2r/w00t00' appears twice"):
        evaluate("vrw", twice, tmp_path / "twice", progress=False)
    clash = dataclasses.replace(second, episode_id=first.episode_id.replace("/", " "))
    with pytest.raises(ValueError, match="share a result file name"):
        evaluate("vrw", dataclasses.replace(tiny_episodes, episodes=(first, clash)), tmp_path / "clash")
    assert not (tmp_path / "twice").exists() and not (tmp_path / "clash").exists()  # refused before writing


def test_a_label_naming_another_method_is_refused(tmp_path, tiny_episodes):
    """Reports take the paper column from the label's method name: VRW labelled `navformer` would be shown
    beside NavFormer's paper numbers."""
    for label in ("navformer", "dt-seed1", "FCA_v2"):
        with pytest.raises(
            ValueError, match=f"the label '{label}' names the method .* evaluated method is 'vrw'"
        ):
            evaluate("vrw", tiny_episodes, tmp_path / label, label=label, progress=False)
        assert not (tmp_path / label).exists()
    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    assert evaluate("vrw", tiny_episodes, tmp_path / "ok", label="vrw-seed1", **kwargs).records
    assert evaluate("vrw", tiny_episodes, tmp_path / "free", label="random-walk", **kwargs).records


def test_a_folder_reused_for_other_episodes_keeps_only_this_runs_files(tmp_path, tiny_episodes):
    """Maps, videos and per-episode results of episodes the new run does not hold are removed (with a
    warning), so the folder shows what its run.json and tables describe."""
    from navformer_rl.evaluation.episodes import make_episode_set

    from .conftest import TINY_SETUP

    out = tmp_path / "vrw"
    evaluate("vrw", tiny_episodes, out, maps_per_setup=2, videos_per_setup=1, progress=False)
    assert len(list((out / "maps").glob("*.png"))) == 2 and len(list((out / "videos").glob("*.mp4"))) == 1
    other = make_episode_set(
        [TINY_SETUP], trials_per_setup=1, trials_per_world=1, seed=9, name="o", max_steps=6
    )
    other = dataclasses.replace(
        other,
        episodes=tuple(dataclasses.replace(e, episode_id="other/" + e.episode_id) for e in other.episodes),
    )
    with pytest.warns(UserWarning, match="removed 5 maps / videos / per-episode results"):
        result = evaluate("vrw", other, out, maps_per_setup=1, videos_per_setup=0, progress=False)
    assert sorted(p.name for p in (out / "maps").glob("*")) == ["other_7.5m-2r_w00t00.png"]
    assert not list((out / "videos").glob("*.mp4"))
    assert sorted(p.name for p in (out / "per_episode").glob("*.json")) == ["other_7.5m-2r_w00t00.json"]
    assert result.files["maps"] == ["maps/other_7.5m-2r_w00t00.png"]


def test_the_model_device_is_checked_before_any_episode(tmp_path, tiny_episodes, checkpoints, monkeypatch):
    import torch

    args = dict(checkpoint=checkpoints["navformer"], progress=False)
    with pytest.raises(
        ValueError, match=r"device \(--device\)='gpu': expected one of \['auto', 'cpu', 'cuda'\]"
    ):
        evaluate("navformer", tiny_episodes, tmp_path / "x", device="gpu", **args)
    # a CUDA device where torch sees none (pretended, so that the check runs on any host)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="device \\(--device\\)=cuda but torch sees no CUDA device"):
        evaluate("navformer", tiny_episodes, tmp_path / "x", device="cuda", **args)
    # a GPU number beyond those present (one GPU pretended)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(ValueError, match=r"cuda:1: torch sees 1 CUDA device\(s\), numbered from 0"):
        evaluate("navformer", tiny_episodes, tmp_path / "x", device="cuda:1", **args)
    monkeypatch.undo()
    with pytest.raises(ValueError, match="your factory places its own model"):
        evaluate(_standing, tiny_episodes, tmp_path / "x", device="auto", progress=False)
    assert not (tmp_path / "x").exists()


def _standing():
    from navformer_rl.baselines import RandomWalkPolicy

    return RandomWalkPolicy()


def test_the_policy_runs_where_the_device_says(tiny_episodes, checkpoints, tmp_path, monkeypatch):
    import torch

    # a machine without CUDA (pretended, so that "auto" means the CPU on any host)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    spec = PolicySpec("navformer", str(checkpoints["navformer"]), device="auto")
    policy, _ = spec.build_with_config()
    assert policy.device.type == "cpu"  # auto on a machine without CUDA
    common = dict(checkpoint=checkpoints["dt"], maps_per_setup=0, videos_per_setup=0, progress=False)
    first = evaluate("dt", tiny_episodes, tmp_path / "dt", **common)
    # "auto" resolving to the CPU reuses the CPU results: their resume keys did not change
    again = evaluate("dt", tiny_episodes, tmp_path / "dt", device="auto", **common)
    assert again.episodes_computed == 0 and again.records == first.records
    assert json.loads((tmp_path / "dt" / "run.json").read_text())["device"] == "cpu"
    vrw = evaluate(
        "vrw", tiny_episodes, tmp_path / "vrw", maps_per_setup=0, videos_per_setup=0, progress=False
    )
    assert json.loads((vrw.out_dir / "run.json").read_text())["device"] is None  # no model to place
