"""Collection on the Ray backend: the same bytes as the local backend, resume, errors, a missing ray.

The Ray tests share one local Ray instance with 2 CPUs (started once for this module: seconds)."""

import shutil
import sys

import pytest

from navformer_rl.data import collect as collect_module
from navformer_rl.data.cli import main as cli_main
from navformer_rl.data.collect import collect, settings_for
from navformer_rl.utils import backends

SETTINGS = settings_for("ca", "small", seed=5, n_trajectories=5, other_robots=(2, 2))
"""5 D_ca trajectories from arena episodes of 3 robots: at least 2 work units
(3 trajectories at most each)."""


@pytest.fixture(scope="module")
def ray_instance():
    """The ``ray`` module with a local instance of 2 CPUs, started here and shut down after the module."""
    ray = pytest.importorskip("ray")
    with backends.session("ray", 2):
        yield ray
    assert not ray.is_initialized()


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory):
    """:data:`SETTINGS` collected on the local backend (in this process: the worker count changes nothing,
    ``test_killed_cli_process_resumes_to_identical_dataset``)."""
    return collect("ca", tmp_path_factory.mktemp("local") / "ca", SETTINGS, workers=1, progress=False)


def test_ray_collection_is_byte_identical_to_the_local_one(
    ray_instance, local_reference, tmp_path, folder_bytes
):
    out = collect("ca", tmp_path / "ca", SETTINGS, workers=2, progress=False, backend="ray")
    assert folder_bytes(out) == folder_bytes(local_reference)
    assert ray_instance.is_initialized()  # a session it found running is left running


def test_ray_collection_resumes_an_interrupted_one_with_units_removed(
    ray_instance, local_reference, tmp_path, folder_bytes
):
    """Units 0 and 1 collected locally, then unit 0 removed: Ray fills the gap, goes on, same bytes."""
    out = tmp_path / "ca"
    calls = {"n": 0}

    def crashing_unit(root, kind, settings, unit):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return collect_module.run_unit(root, kind, settings, unit)

    with pytest.raises(KeyboardInterrupt):
        collect("ca", out, SETTINGS, workers=1, progress=False, unit_fn=crashing_unit)
    collect_module.run_unit(str(out), "ca", SETTINGS, 1)
    shutil.rmtree(out / "shards" / "unit-000000")
    assert [p.name for p in (out / "shards").iterdir()] == ["unit-000001"]
    collect("ca", out, SETTINGS, workers=2, progress=False, backend="ray")
    assert folder_bytes(out) == folder_bytes(local_reference)


def _inverse(x: float) -> float:
    return 1.0 / x


def test_a_failing_ray_task_raises_its_own_error_and_cancels_the_rest(ray_instance):
    units = [(i, (float(i - 2),)) for i in range(8)]  # unit 2 divides by zero
    with pytest.raises(ZeroDivisionError, match="division by zero") as error:
        with backends.open_backend("ray", 2) as pool:
            assert pool.remote and pool.slots == 4
            for _ in backends.run_units(pool, _inverse, units):
                assert pool.in_flight <= pool.slots
    assert type(error.value) is ZeroDivisionError  # the task's own error, not Ray's wrapper
    assert pool.in_flight == 0 and ray_instance.is_initialized()


def test_ray_runs_only_the_collection_units(tmp_path):
    pytest.importorskip("ray")
    with pytest.raises(ValueError, match="unit_fn applies to the local backend"):
        collect("ca", tmp_path, SETTINGS, backend="ray", unit_fn=lambda *args: {})


def test_an_address_where_nothing_answers_is_refused_at_once():
    with pytest.raises(
        ValueError, match=r"^ray address 'ray://127.0.0.1:1': nothing answers at 127.0.0.1:1 "
    ):
        backends._check_reachable("ray://127.0.0.1:1")
    backends._check_reachable("auto")  # left to Ray


def test_backend_mistakes_end_in_one_line(tmp_path, capsys, monkeypatch):
    out = str(tmp_path / "ca")
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["collect", "ca", "--out", out, "--backend", "foo"])
    assert exit_info.value.code == 2
    assert "argument --backend: invalid choice: 'foo' (choose from 'local', 'ray')" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"^backend 'foo': expected one of local, ray$"):
        collect("ca", out, SETTINGS, backend="foo")
    assert cli_main(["collect", "ca", "--out", out, "--ray-address", "auto"]) == 2
    assert capsys.readouterr().err == "navformer collect: error: --ray-address applies to --backend ray\n"
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as without the extra
    assert cli_main(["collect", "ca", "--out", out, "--backend", "ray", "--no-progress"]) == 2
    assert capsys.readouterr().err == (
        'navformer collect: error: ray is not installed: pip install "navformer_rl[distributed]"\n'
    )
    assert not (tmp_path / "ca").exists()
