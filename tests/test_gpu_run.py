"""benchmarks/gpu_run.sh and gpu_run.py, the GPU machine's one call, at a tiny scale on CPU: every figure of
the JSON, partial results when interrupted, the parallel data writer's bytes, and the carried wheels against
the imports of a real run."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"

GPU_MACHINE_PACKAGES = frozenset(
    """absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build
    certifi charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings
    cuda-core cuda-pathfinder cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils
    execnet filelock flatbuffers flax fonttools formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet
    httpcore httpx huggingface-hub humanize hypothesis idna imageio iniconfig interface-meta jax
    jax-cuda13-pjrt jax-cuda13-plugin jaxlib jaxtyping jinja2 joblib kiwisolver lazy-loader lightning
    lightning-utilities linear-operator lineax llvmlite lxml markdown markdown-it-py markupsafe matplotlib
    mdurl meson ml-dtypes mpi4py mpmath msgpack multidict multipledispatch mypy-extensions nanobind narwhals
    networkx ninja numba numba-cuda numpy numpyro nvidia-cublas nvidia-cuda-cupti nvidia-cuda-nvrtc
    nvidia-cuda-runtime nvidia-cudnn-cu13 nvidia-cufft nvidia-cufile nvidia-curand nvidia-cusolver
    nvidia-cusparse nvidia-cusparselt-cu13 nvidia-ml-py nvidia-nccl-cu13 nvidia-nvjitlink
    nvidia-nvshmem-cu13 nvidia-nvtx onnx onnx-ir onnxruntime onnxscript opencv-python-headless optax
    opt-einsum opt-einsum-fx optimistix orbax-checkpoint packaging pandas pathspec patsy peft pillow pip
    pluggy portalocker prometheus-client propcache protobuf psutil pyarrow pybind11 py-cpuinfo pygments
    pyparsing pyproject-hooks pyre-extensions pytest pytest-benchmark pytest-cov pytest-mock pytest-timeout
    pytest-xdist python-dateutil pytorch-lightning pyyaml regex requests rich sacrebleu safetensors
    scikit-build-core scikit-image scikit-learn scipy seaborn sentencepiece sentence-transformers setuptools
    shellingham simplejson six sortedcontainers statsmodels sympy tabulate tensorboard
    tensorboard-data-server tensorstore threadpoolctl tifffile tiktoken timm tokenizers toolz torch
    torchaudio torchdiffeq torch-geometric torchmetrics torchvision tqdm transformers treescope triton typer
    typing-extensions typing-inspect urllib3 uvloop wadler-lindig werkzeug wheel wrapt xarray xxhash yarl
    zipp""".split()
)
"""The GPU machine's Python packages (/work/.library/device/KINDS.md, as read on 2026-11-17)."""


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def carried_wheels() -> dict[str, str]:
    """``{normalised name: version}`` of the ``WHEELS=( ... )`` list of gpu_wheels.sh."""
    text = (BENCH / "gpu_wheels.sh").read_text()
    block = re.search(r"^WHEELS=\((.*?)^\)", text, re.M | re.S).group(1)
    specs = [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith("#")]
    return {normalise(spec.split("==")[0]): spec.split("==")[1] for spec in specs}


@pytest.fixture(scope="module")
def gpu_run():
    spec = importlib.util.spec_from_file_location("gpu_run", BENCH / "gpu_run.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["gpu_run"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules["gpu_run"]


def test_scripts_are_valid_bash():
    for script in ("gpu_run.sh", "gpu_wheels.sh"):
        done = subprocess.run(["bash", "-n", str(BENCH / script)], capture_output=True, text=True)
        assert done.returncode == 0, f"{script}: {done.stderr}"


def test_the_wheels_are_one_pinned_version_each_of_what_is_tested_here():
    specs = carried_wheels()
    assert {"torchrl", "tensordict", "kornia", "omegaconf", "gymnasium"} <= set(specs)
    assert not set(specs) & GPU_MACHINE_PACKAGES, "carried, but already on the GPU machine"
    for name, version in specs.items():
        assert importlib.metadata.version(name) == version, (
            f"{name}: carried {version}, tested here otherwise"
        )


def test_bad_arguments_are_one_line_errors(gpu_run, capsys):
    with pytest.raises(SystemExit) as exit_info:
        gpu_run.parse_args(["--device", "tpu", "--window", "3", "--variants", "warp drive"])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--device 'tpu'" in error and "--window 3" in error and "'warp drive'" in error


def test_parallel_shards_give_the_bytes_of_make_synthetic_dataset(gpu_run, tmp_path):
    from navformer_rl.data import make_synthetic_dataset

    scale = dataclasses.replace(gpu_run.TINY, counts={"e": 3, "ca": 2, "ssl": 4})  # the last e unit: 1 of 2
    paths, stats = gpu_run.make_datasets(tmp_path / "pool", scale, scale.lengths, workers=2)
    assert stats["written"] == ["ca", "e", "ssl"] and stats["units"] == 2 + 1 + 1
    for kind, path in paths.items():
        lo, hi = scale.lengths[kind]
        reference = make_synthetic_dataset(
            tmp_path / "plain" / kind,
            kind,
            scale.counts[kind],
            lo,
            hi,
            seed=7,
            items_per_shard=scale.items_per_shard[kind],
        )
        ours, theirs = (json.loads((p / "metadata.json").read_text()) for p in (path, reference))
        assert ours["content_hashes"] == theirs["content_hashes"] and ours["settings"] == theirs["settings"]
    _, again = gpu_run.make_datasets(tmp_path / "pool", scale, scale.lengths, workers=2)
    assert again["reused"] == ["ca", "e", "ssl"] and again["written"] == [] and again["images_per_s"] is None


def test_an_interrupted_run_keeps_the_figures_measured_so_far(gpu_run, tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise gpu_run.Interrupted("SIGTERM")

    monkeypatch.setattr(gpu_run, "measure_training", interrupted)
    out = tmp_path / "out"
    args = [
        "--device",
        "cpu",
        "--tiny",
        "--out",
        str(out),
        "--data",
        str(tmp_path / "data"),
        "--workers",
        "1",
    ]
    gpu_run.run(gpu_run.parse_args(args))
    saved = json.loads((out / "gpu_run.json").read_text())
    assert saved["status"] == "interrupted (SIGTERM)" and saved["errors"] == []
    assert saved["phases"]["data"]["written"] == ["ca", "e", "ssl"] and saved["phases"]["data"]["images"] > 0
    assert saved["phases"]["peak"]["n"] == 128 and saved["phases"]["peak"]["tflops"] > 0
    assert saved["summary"]["peak_tflops"] == saved["phases"]["peak"]["tflops"]
    assert saved["summary"]["s_per_iteration"] is None and "train" not in saved["phases"]
    table = (out / "gpu_run.md").read_text()
    assert "interrupted (SIGTERM)" in table and "| iterations/s | - |" in table


def check_report(report: dict, out: Path) -> None:
    """Every figure of a complete tiny CPU run's ``gpu_run.json`` is present and consistent."""
    assert report["status"] == "complete" and report["errors"] == []
    assert {"gpu_run.json", "gpu_run.md", "profile.txt"} <= {p.name for p in out.iterdir()}
    summary, train = report["summary"], report["phases"]["train"]
    s = summary["s_per_iteration"]
    assert 0 < s < 60 and summary["iterations_per_s"] == pytest.approx(1 / s)
    assert summary["projected_10k_s"] == pytest.approx(10_000 * s)
    assert summary["projected_10k_min"] == pytest.approx(10_000 * s / 60)
    assert summary["goal_met"] == (10_000 * s <= 1200) and summary["goal_10k_s"] == 1200
    assert summary["peak_tflops"] > 0 and summary["achieved_tflops"] > 0
    assert summary["mfu"] == pytest.approx(summary["achieved_tflops"] / summary["peak_tflops"])
    assert summary["gpu_memory_peak_gib"] is None and summary["gpu_busy_fraction"] is None  # CPU
    assert train["iterations"] == 2 and len(train["window_s_per_iteration"]) == 1
    assert (
        set(train["median_s"]) == set(train["flops_per_iteration"]) == {"exploration", "collision_avoidance"}
    )
    assert all(f > 1e6 for f in train["flops_per_iteration"].values())
    assert train["achieved_tflops"] == pytest.approx(train["flops_mean"] / s / 1e12)
    assert {"sample", "forward_backward", "optimizer"} <= set(train["phases_s"])
    assert "model.autocast_dtype=bfloat16" in train["overrides"] and len(train["warmup_s"]) == 2
    assert train["profile"]["iterations"] == 2 and "aten::" in (out / "profile.txt").read_text()
    data = report["phases"]["data"]
    assert {kind: d["items"] for kind, d in data["datasets"].items()} == {"e": 6, "ca": 8, "ssl": 16}
    assert data["images"] > 0 and data["bytes"] > 0 and data["paper_scale_projected_s"] > 0
    table = (out / "gpu_run.md").read_text()
    assert "| projected 10,000 iterations (goal <= 20 min) |" in table and "| MFU" in table


def test_tiny_cpu_run_writes_every_figure(gpu_run, tmp_path):
    out = tmp_path / "out"
    args = ["--device", "cpu", "--tiny", "--out", str(out), "--data", str(tmp_path / "data")]
    report = gpu_run.run(gpu_run.parse_args([*args, "--workers", "2", "--variants", "no prefetch"]))
    check_report(report, out)
    assert json.loads((out / "gpu_run.json").read_text())["summary"] == report["summary"]
    variant = report["phases"]["variants"]["no prefetch"]
    assert variant["iterations"] == 2 and "data.prefetch=false" in variant["overrides"]
    assert "| no prefetch |" in (out / "gpu_run.md").read_text()


def hidden_ray_env(tmp_path: Path) -> dict[str, str]:
    """The environment of a subprocess in which ``ray`` cannot be imported, as on the GPU machine."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "sitecustomize.py").write_text(
        "import sys\nsys.modules['ray'] = None  # not on the GPU machine\n"
    )
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(hide), "RL_LOGGING_LEVEL": "WARNING"}


def check_wheels_cover(imported: list[str]) -> None:
    names = {normalise(name) for name in imported}
    missing = names - set(carried_wheels()) - GPU_MACHINE_PACKAGES - {"navformer-rl"}
    assert not missing, f"add to benchmarks/gpu_wheels.sh: {sorted(missing)}"
    assert {"torchrl", "tensordict", "kornia", "omegaconf", "gymnasium"} <= names and "ray" not in names


def test_the_wheels_cover_the_training_paths_imports(tmp_path):
    """What the trainer's modules import at load time is carried or already on the GPU machine (the slow
    test below checks the imports of a whole run)."""
    code = (
        "import sys; before = set(sys.modules)\n"
        "import navformer_rl.training.run, navformer_rl.training.trainer, navformer_rl.objectives\n"
        "import navformer_rl.data.synthetic, navformer_rl.modules\n"
        "import torchrl.objectives, torchrl.record.loggers.csv\n"
        "navformer_rl.training.load_train_config([])  # omegaconf, imported when a configuration is read\n"
        "import importlib.metadata as md, json\n"
        "dists = md.packages_distributions()\n"
        "new = {m.split('.')[0] for m in set(sys.modules) - before}\n"
        "print(json.dumps(sorted({d for m in new for d in dists.get(m, [])})))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        env=hidden_ray_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    check_wheels_cover(json.loads(done.stdout.splitlines()[-1]))


def test_the_navformer_command_loads_without_the_simulator_or_ffmpeg(tmp_path):
    """``python -m navformer_rl train ...`` runs where neither pybullet nor imageio-ffmpeg is installed (the
    GPU machine): the command's modules load, and asking for a video names the missing encoder."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "sitecustomize.py").write_text(
        "import sys\nfor name in ('ray', 'pybullet', 'imageio_ffmpeg'):\n    sys.modules[name] = None\n"
    )
    code = (
        "import navformer_rl.cli.main, navformer_rl.training.run\n"
        "from navformer_rl.utils.mp4 import VideoEncoderError, ffmpeg_executable\n"
        "try:\n    ffmpeg_executable()\nexcept VideoEncoderError as error:\n    print(error)\n"
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(hide), "RL_LOGGING_LEVEL": "WARNING"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "no ffmpeg binary for the mp4 videos" in done.stdout and "imageio-ffmpeg" in done.stdout


@pytest.mark.slow
def test_tiny_cpu_run_through_gpu_run_sh(tmp_path):
    """The whole call as on the GPU machine, less the wheel install: the shell script, a fresh process, ray
    hidden, every figure, a data-generating variant, and the wheels against every import of the run."""
    out = tmp_path / "out"
    env = {**hidden_ray_env(tmp_path), "OUT": str(out), "BUDGET_S": "300", "PYTHON": sys.executable}
    env["GPU_RUN_INSTALL"] = "0"
    args = ["--device", "cpu", "--tiny", "--data", str(tmp_path / "data"), "--workers", "2"]
    done = subprocess.run(
        ["bash", str(BENCH / "gpu_run.sh"), *args, "--variants", "wide trajectory lengths"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    report = json.loads((out / "gpu_run.json").read_text())
    check_report(report, out)
    assert {"env.txt", "gpu_run.log"} <= {p.name for p in out.iterdir()}
    assert "nvidia-smi: not found" in (out / "env.txt").read_text()
    wide = report["phases"]["variants"]["wide trajectory lengths"]
    assert wide["iterations"] == 2 and wide["s_per_iteration"] > 0
    assert wide["data"]["written"] == ["ca", "e"] and wide["data"]["reused"] == ["ssl"]  # D_ssl: same pairs
    check_wheels_cover(report["env"]["imported_distributions"])
