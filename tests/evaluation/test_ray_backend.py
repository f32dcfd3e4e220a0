"""Evaluation on the Ray backend: the same rows, maps and video as the local backend, resume across
backends, a missing ray.

The Ray tests share one local Ray instance with 2 CPUs (started once for this module: seconds)."""

import json
import sys

import pytest

from navformer_rl.cli.main import main as navformer
from navformer_rl.evaluation.harness import evaluate
from navformer_rl.utils import backends


@pytest.fixture(scope="module")
def ray_instance():
    """The ``ray`` module with a local instance of 2 CPUs, started here and shut down after the module."""
    ray = pytest.importorskip("ray")
    with backends.session("ray", 2):
        yield ray
    assert not ray.is_initialized()


def test_ray_evaluation_gives_the_local_rows_and_visuals(ray_instance, vrw_run, tiny_episodes, tmp_path):
    """VRW (seed 3) with a map and a video of the first episode, as the local ``vrw_run``: byte-identical
    rows, map and video (the Ray tasks return them, this process writes them)."""
    local, _ = vrw_run
    out = tmp_path / "ray"
    result = evaluate(
        "vrw", tiny_episodes, out, maps_per_setup=1, videos_per_setup=1, progress=False, seed=3,
        workers=2, backend="ray",
    )  # fmt: skip
    assert result.episodes_computed == 2
    for name in ("episodes.jsonl", "summary.csv", "maps/7.5m-2r_w00t00.png", "videos/7.5m-2r_w00t00.mp4"):
        assert (out / name).read_bytes() == (local / name).read_bytes(), name
    assert json.loads((out / "run.json").read_text())["backend"] == "ray"
    assert ray_instance.is_initialized()  # a session it found running is left running


def test_ray_and_local_runs_resume_each_other(ray_instance, tiny_episodes, tmp_path):
    out = tmp_path / "vrw"
    common = dict(maps_per_setup=0, videos_per_setup=0, progress=False, seed=3)
    evaluate("vrw", tiny_episodes, out, **common)
    first = (out / "episodes.jsonl").read_bytes()
    (out / "per_episode" / "7.5m-2r_w00t01.json").unlink()
    resumed = evaluate("vrw", tiny_episodes, out, workers=2, backend="ray", **common)
    assert resumed.episodes_computed == 1 and (out / "episodes.jsonl").read_bytes() == first
    assert evaluate("vrw", tiny_episodes, out, **common).episodes_computed == 0  # Ray's rows reused


def test_backend_mistakes_end_in_one_line(tiny_episodes, tmp_path, capsys, monkeypatch):
    out = tmp_path / "eval"
    command = ["evaluate", "--method", "vrw", "--protocol", "smoke", "--out", str(out)]
    with pytest.raises(SystemExit) as exit_info:
        navformer([*command, "--backend", "foo"])
    assert exit_info.value.code == 2
    assert "argument --backend: invalid choice: 'foo' (choose from 'local', 'ray')" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"^backend 'foo': expected one of local, ray$"):
        evaluate("vrw", tiny_episodes, out, backend="foo")
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as without the extra
    assert navformer([*command, "--backend", "ray"]) == 2
    assert capsys.readouterr().err == (
        'navformer evaluate: error: ray is not installed: pip install "navformer_rl[distributed]"\n'
    )
    assert not out.exists()
