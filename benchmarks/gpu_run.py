"""One GPU-machine call: training throughput of the paper configuration, against the GPU's bf16 matmul rate.

    bash benchmarks/gpu_run.sh                                        # on the GPU machine (see README.md)
    .venv/bin/python benchmarks/gpu_run.py --device cpu --tiny --out /tmp/gpu_run   # here, in seconds

Phases, each written to ``<out>/gpu_run.json`` (and the table ``<out>/gpu_run.md``) as soon as it ends, so a
call stopped by its time limit still returns every figure measured so far:

1. ``data``: synthetic datasets in the real on-disk format (``navformer_rl.data.synthetic``) with the paper's
   mean trajectory lengths (D_e 98 steps, drawn in [90, 106]; D_ca 63, in [55, 71]) and ``--data-scale``
   times the paper's counts (3,496 / 7,467 trajectories, 98,000 pairs), their shards written by
   ``--workers`` processes (forked before CUDA starts). Times it and projects the paper-scale generation.
   Complete datasets of the same settings under ``--data`` are reused (reported as such).
2. ``peak``: square bf16 matmuls (8192^3; 128^3 with ``--tiny``), timed with CUDA events; the median
   TFLOP/s is the reference for the model FLOP utilisation (MFU).
3. ``train``: the paper configuration (defaults of ``train.yaml``: model, batches of 25 / 150 trajectories
   and 512 pairs, both optimisers, EMA) with bf16 autocast, through ``build_trainer`` and
   ``Trainer.step()`` (sampling, prefetching, copies to the GPU included). ``--warmup`` iterations, one
   D_e and one D_ca iteration under ``torch.utils.flop_counter.FlopCounterMode`` (not timed), then
   ``--iterations`` timed in windows of ``--window``; each ``step`` ends with a CUDA synchronisation. Reports
   the median seconds per iteration over windows, iterations/s, the projected time of 10,000 iterations
   (goal: 20 min), achieved TFLOP/s and MFU, the GPU memory peak and ``time/<phase>`` means.
4. ``profile``: a few more iterations under ``torch.profiler``; the top operators go to ``profile.txt``
   and the GPU's busy fraction (kernel time / wall time) to the JSON.
5. ``variants`` while the budget lasts, each a fresh trainer with one change (``--variants``).

``--budget-s`` bounds the whole run: a phase starts only when its estimate fits, the timed loop stops
early when the budget runs low, and SIGTERM / SIGALRM (``budget + 30 s``) end the run with the figures
measured so far (``status`` says how it ended). ``--tiny`` shrinks data, model and iteration counts so the
same code runs on CPU in seconds (tests/test_gpu_run.py).
"""

from __future__ import annotations

import sys

_MODULES_AT_START = set(sys.modules)  # before torch: the imports of a run, for imported_distributions

import argparse  # noqa: E402
import contextlib  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import signal  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from concurrent.futures import Executor, ProcessPoolExecutor  # noqa: E402
from dataclasses import asdict, dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import torch  # noqa: E402

PAPER_COUNTS = {"e": 3496, "ca": 7467, "ssl": 98_000}
"""Paper §V: D_e / D_ca trajectories, D_ssl pairs."""
PAPER_FRAMES = 342_954 + 469_378 + 2 * 98_000
"""Images of the paper's three datasets (D_e and D_ca steps, two images per D_ssl pair)."""
PAPER_LENGTHS = {"e": (90, 106), "ca": (55, 71), "ssl": (1, 1)}
"""Trajectory lengths drawn uniformly in these ranges: the paper's means (98.1 / 62.9 steps)."""
WIDE_LENGTHS = {"e": (11, 185), "ca": (11, 115), "ssl": (1, 1)}
"""The same means with the spread of our collected data (docs/datasets.md): batches padded further."""
ITERATIONS_10K = 10_000
GOAL_10K_S = 20 * 60
"""Goal: the paper's 10,000 iterations in at most 20 minutes on one H200."""
TASKS = ("exploration", "collision_avoidance")
VARIANTS: dict[str, list[str]] = {
    "no prefetch": ["data.prefetch=false"],
    "wide trajectory lengths": [],  # other datasets: WIDE_LENGTHS
    "encoders frozen in L_DT": ["encoder_training=frozen"],
    "fp32 (no autocast)": ["model.autocast_dtype=null"],
    "channels_last=false": ["model.channels_last=false"],
    "space_to_depth=false": ["model.space_to_depth=false"],
}
"""Changes measured after the main configuration, in this order, while the budget lasts."""
WIDE_VARIANT = "wide trajectory lengths"


@dataclass(frozen=True)
class Scale:
    """Sizes of one run: dataset counts and lengths, batches, model overrides, iteration counts."""

    counts: dict[str, int]
    lengths: dict[str, tuple[int, int]]
    wide_lengths: dict[str, tuple[int, int]]
    items_per_shard: dict[str, int]
    batches: dict[str, int]
    model: tuple[str, ...]
    matmul_n: int
    warmup: int
    iterations: int
    window: int
    profile_iterations: int


def paper_scale(data_scale: float, iterations: int, window: int, warmup: int) -> Scale:
    counts = {kind: max(math.ceil(n * data_scale), 1) for kind, n in PAPER_COUNTS.items()}
    return Scale(
        counts=counts,
        lengths=PAPER_LENGTHS,
        wide_lengths=WIDE_LENGTHS,
        items_per_shard={"e": 16, "ca": 16, "ssl": 256},
        batches={"e": 25, "ca": 150, "ssl": 512},
        model=(),
        matmul_n=8192,
        warmup=warmup,
        iterations=iterations,
        window=window,
        profile_iterations=4,
    )


TINY = Scale(
    counts={"e": 6, "ca": 8, "ssl": 16},
    lengths={"e": (5, 8), "ca": (4, 6), "ssl": (1, 1)},
    wide_lengths={"e": (2, 11), "ca": (2, 8), "ssl": (1, 1)},
    items_per_shard={"e": 2, "ca": 2, "ssl": 4},
    batches={"e": 2, "ca": 3, "ssl": 4},
    model=(
        "model.d_embed=16",
        "model.n_heads=2",
        "model.d_head=8",
        "model.n_blocks=1",
        "ssl.projection_dim=8",
        "ssl.hidden_dim=16",
    ),
    matmul_n=128,
    warmup=2,
    iterations=2,
    window=2,
    profile_iterations=2,
)


class Interrupted(BaseException):
    """SIGTERM (the caller's timeout) or SIGALRM (the internal limit): stop, keep what was measured."""


class Budget:
    """Seconds left of ``seconds`` since construction."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.start = time.monotonic()

    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def left(self) -> float:
        return self.seconds - self.elapsed()


@dataclass
class Report:
    """The results, saved atomically as ``gpu_run.json`` and ``gpu_run.md`` after every phase."""

    out: Path
    budget: Budget
    data: dict[str, Any] = field(default_factory=dict)

    def save(self) -> None:
        from navformer_rl.utils.durable import atomic_write_text

        self.data["elapsed_s"] = round(self.budget.elapsed(), 2)
        atomic_write_text(self.out / "gpu_run.json", json.dumps(self.data, indent=2, default=str) + "\n")
        atomic_write_text(self.out / "gpu_run.md", markdown(self.data))

    def error(self, phase: str, err: BaseException) -> None:
        """Record ``phase``'s exception in one line (the traceback goes to stderr, i.e. the log)."""
        traceback.print_exc()
        self.data["errors"].append(
            f"{phase}: {type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
        )
        self.save()


# -- 2. the matmul peak -------------------------------------------------------------------------------------
def matmul_peak(device: torch.device, n: int, repeats: int = 20, warmup: int = 3) -> dict[str, Any]:
    """Median rate of ``[n, n] @ [n, n]`` bf16 matmuls (CUDA events on a GPU, wall clock on CPU)."""
    a = torch.randn(n, n, device=device).to(torch.bfloat16)
    b = torch.randn(n, n, device=device).to(torch.bfloat16)
    c = torch.empty(n, n, device=device, dtype=torch.bfloat16)
    for _ in range(warmup):
        torch.matmul(a, b, out=c)
    times = []
    if device.type == "cuda":
        torch.cuda.synchronize(device)
        events = [
            (torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True))
            for _ in range(repeats)
        ]
        for start, end in events:
            start.record()
            torch.matmul(a, b, out=c)
            end.record()
        torch.cuda.synchronize(device)
        times = [start.elapsed_time(end) / 1e3 for start, end in events]
    else:
        for _ in range(repeats):
            start_s = time.perf_counter()
            torch.matmul(a, b, out=c)
            times.append(time.perf_counter() - start_s)
    median = statistics.median(times)
    return {
        "n": n,
        "dtype": "bfloat16",
        "repeats": repeats,
        "median_s": median,
        "tflops": 2 * n**3 / median / 1e12,
        "tflops_best": 2 * n**3 / min(times) / 1e12,
    }


# -- 1. synthetic datasets ----------------------------------------------------------------------------------
def _write_unit(root: str, kind: str, unit: int, items: int, min_len: int, max_len: int, seed: int) -> int:
    """Shard ``unit`` of ``make_synthetic_dataset(root, kind, ..., seed, items_per_shard=items)``, the same
    bytes (runs in a worker process); returns its item count."""
    from navformer_rl.data import synthetic
    from navformer_rl.data.schema import DatasetKind
    from navformer_rl.data.writer import write_shard

    torch.set_num_threads(1)
    kind_ = DatasetKind.parse(kind)
    write_shard(root, kind_, unit, *synthetic.synthetic_unit(kind_, unit, items, min_len, max_len, seed))
    return items


def _finalize(root: str, kind: str, n: int, min_len: int, max_len: int, seed: int, items: int) -> str:
    """``make_synthetic_dataset`` over the shards written by :func:`_write_unit` (it only consolidates)."""
    from navformer_rl.data import make_synthetic_dataset

    torch.set_num_threads(1)
    return str(make_synthetic_dataset(root, kind, n, min_len, max_len, seed=seed, items_per_shard=items))


def _is_complete(root: Path) -> bool:
    try:
        return json.loads((root / "metadata.json").read_text()).get("status") == "complete"
    except (OSError, ValueError):
        return False


@contextlib.contextmanager
def _executor(workers: int) -> Iterator[Executor | None]:
    """A process pool of ``workers`` (fork while CUDA is not initialised, else spawn), or None for 1."""
    if workers <= 1:
        yield None
        return
    method = "spawn" if torch.cuda.is_initialized() else "fork"
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method))
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _run_all(pool: Executor | None, calls: list[tuple[Callable, tuple]]) -> list[Any]:
    if pool is None:
        return [fn(*args) for fn, args in calls]
    return [future.result() for future in [pool.submit(fn, *args) for fn, args in calls]]


def make_datasets(
    root: Path, scale: Scale, lengths: dict[str, tuple[int, int]], workers: int, seed: int = 7
) -> tuple[dict[str, Path], dict[str, Any]]:
    """Write (or reuse) D_e, D_ca and D_ssl under ``root``; returns their paths and the timings."""
    paths, pending = {}, {}
    for kind, n in scale.counts.items():
        lo, hi = lengths[kind]
        items = scale.items_per_shard[kind]
        paths[kind] = root / f"{kind}-n{n}-len{lo}-{hi}-shard{items}-seed{seed}"
        if not _is_complete(paths[kind]):
            pending[kind] = (str(paths[kind]), kind, n, lo, hi, seed, items)
    import navformer_rl.data.synthetic  # noqa: F401  (forked workers inherit the imports)
    import navformer_rl.data.writer  # noqa: F401

    start = time.perf_counter()
    with _executor(workers) as pool:
        units = [
            (_write_unit, (path, kind, unit, items, lo, hi, seed))
            for path, kind, n, lo, hi, seed, items in pending.values()
            for unit in range(math.ceil(n / items))
            if not (Path(path) / "shards" / f"unit-{unit:06d}").is_dir()
        ]
        _run_all(pool, units)
        shards_s = time.perf_counter() - start
        _run_all(pool, [(_finalize, args) for args in pending.values()])
    total_s = time.perf_counter() - start
    frames, size = 0, 0
    per_kind = {}
    for kind, path in paths.items():
        counts = json.loads((path / "metadata.json").read_text())["counts"]
        images = counts["rows"] * (2 if kind == "ssl" else 1)
        nbytes = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
        per_kind[kind] = {"items": counts["items"], "images": images, "bytes": nbytes, "path": str(path)}
        frames += images
        size += nbytes
    written = sum(per_kind[kind]["images"] for kind in pending)
    stats = {
        "reused": sorted(set(paths) - set(pending)),
        "written": sorted(pending),
        "workers": workers,
        "units": len(units),
        "shards_s": shards_s,
        "finalize_s": total_s - shards_s,
        "total_s": total_s,
        "images": frames,
        "bytes": size,
        "images_per_s": written / total_s if written else None,
        "paper_scale_projected_s": PAPER_FRAMES / (written / total_s) if written else None,
        "datasets": per_kind,
    }
    return paths, stats


# -- 3. training --------------------------------------------------------------------------------------------
def global_flop_counter() -> Any:
    """``FlopCounterMode`` without its per-module tracker (whose hooks cannot hash TensorDict-parametrised
    modules), as in ``bench_training.py``; counts the whole step under "Global"."""
    from torch.utils.flop_counter import FlopCounterMode

    class NoModuleTracker:
        parents = {"Global"}

        def __enter__(self) -> NoModuleTracker:
            return self

        def __exit__(self, *args: object) -> None:
            return None

    counter = FlopCounterMode(display=False)
    counter.mod_tracker = NoModuleTracker()
    return counter


def task_of(metrics: dict[str, float]) -> str:
    return next(task for task in TASKS if f"loss_dt_{task}" in metrics)


def train_overrides(paths: dict[str, Path], device: str, scale: Scale, out_dir: Path) -> list[str]:
    """The paper configuration (``train.yaml``'s defaults) with bf16 autocast on ``paths``' datasets."""
    return [
        f"data.exploration_path={paths['e']}",
        f"data.collision_path={paths['ca']}",
        f"data.ssl_path={paths['ssl']}",
        f"data.exploration_batch_trajs={scale.batches['e']}",
        f"data.collision_batch_trajs={scale.batches['ca']}",
        f"data.ssl_batch_pairs={scale.batches['ssl']}",
        f"device={device}",
        "model.autocast_dtype=bfloat16",
        f"optim.iterations={ITERATIONS_10K}",
        "logger.backend=none",
        "logger.progress=false",
        f"output_dir={out_dir}",
        *scale.model,
    ]


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure_training(
    overrides: list[str],
    iterations: int,
    scale: Scale,
    budget: Budget,
    reserve_s: float,
    profile_to: Path | None = None,
) -> dict[str, Any]:
    """Build a trainer from ``overrides`` and time ``iterations`` of ``Trainer.step()`` (see module doc)."""
    from torchrl._utils import timeit

    from navformer_rl.training import build_trainer, load_train_config

    start = time.perf_counter()
    trainer = build_trainer(load_train_config(overrides))
    device = trainer.device
    result: dict[str, Any] = {"build_s": time.perf_counter() - start, "overrides": overrides}
    try:
        result["warmup_s"] = []
        for _ in range(scale.warmup):  # the first ones pay for CUDA / cuBLAS / cuDNN set-up and allocations
            step_start = time.perf_counter()
            trainer.step()
            result["warmup_s"].append(time.perf_counter() - step_start)
        flops: dict[str, float] = {}
        for _ in range(2):  # one D_e and one D_ca iteration, counted, not timed
            counter = global_flop_counter()
            try:
                with counter:
                    metrics = trainer.step()
                flops[task_of(metrics)] = float(counter.get_total_flops())
            except Exception as err:  # a missing FLOP formula must not cost the timing
                result["flops_error"] = f"{type(err).__name__}: {err}"
                trainer.step()
        _sync(device)
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)
        timeit.erase()
        windows: list[float] = []
        per_task: dict[str, list[float]] = {task: [] for task in TASKS}
        frames: dict[str, list[float]] = {task: [] for task in TASKS}
        while len(windows) * scale.window < iterations:
            if windows and budget.left() < reserve_s + 2 * max(windows) * scale.window:
                result["stopped_early"] = f"budget: {len(windows) * scale.window} of {iterations} iterations"
                break
            window_start = time.perf_counter()
            for _ in range(scale.window):
                metrics = trainer.step()  # ends with a CUDA synchronisation
                per_task[task_of(metrics)].append(metrics["iteration_s"])
                frames[task_of(metrics)].append(metrics["frames"])
            windows.append((time.perf_counter() - window_start) / scale.window)
        result["phases_s"] = timeit.todict(percall=True)
        s_per_it = statistics.median(windows)
        result.update(
            {
                "iterations": len(windows) * scale.window,
                "window": scale.window,
                "window_s_per_iteration": windows,
                "s_per_iteration": s_per_it,
                "iterations_per_s": 1 / s_per_it,
                "projected_10k_s": s_per_it * ITERATIONS_10K,
                "median_s": {task: statistics.median(v) for task, v in per_task.items() if v},
                "frames_per_iteration": {task: statistics.mean(v) for task, v in frames.items() if v},
                "frames_per_s": sum(map(sum, frames.values())) / (s_per_it * len(windows) * scale.window),
                "flops_per_iteration": flops,
            }
        )
        if len(flops) == 2:
            mean_flops = sum(flops.values()) / 2
            result["flops_mean"] = mean_flops
            result["achieved_tflops"] = mean_flops / s_per_it / 1e12
        if device.type == "cuda":
            result["gpu_memory_peak_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
            result["gpu_memory_reserved_gib"] = torch.cuda.max_memory_reserved(device) / 2**30
        if profile_to is not None and budget.left() > reserve_s + 4 * s_per_it * scale.profile_iterations:
            try:
                result["profile"] = profile_steps(trainer, scale.profile_iterations, profile_to, s_per_it)
            except Exception as err:  # the profiler must not cost the timing
                result["profile"] = {"error": f"{type(err).__name__}: {err}".splitlines()[0]}
    finally:
        trainer.close()
        del trainer
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            torch.cuda.empty_cache()
    return result


# -- 4. profile ---------------------------------------------------------------------------------------------
def profile_steps(trainer: Any, iterations: int, path: Path, s_per_iteration: float) -> dict[str, Any]:
    """``iterations`` steps under ``torch.profiler``; the top operators to ``path``; returns the kernel time
    per iteration and its fraction of ``s_per_iteration`` (the unprofiled time) on a GPU."""
    from torch.profiler import ProfilerActivity, profile

    cuda = trainer.device.type == "cuda"
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    start = time.perf_counter()
    with profile(activities=activities) as prof:
        for _ in range(iterations):
            trainer.step()
        _sync(trainer.device)
    wall = (time.perf_counter() - start) / iterations
    averages = prof.key_averages()
    device_key = "self_device_time_total" if cuda else "self_cpu_time_total"
    tables = [f"# {iterations} iterations, {wall:.4f} s each (profiled)\n"]
    if cuda:
        tables.append(
            "## by device (GPU) time\n" + averages.table(sort_by="self_device_time_total", row_limit=40)
        )
    tables.append("## by CPU time\n" + averages.table(sort_by="self_cpu_time_total", row_limit=40))
    path.write_text("\n\n".join(tables) + "\n")
    result: dict[str, Any] = {"iterations": iterations, "wall_s_per_iteration": wall, "table": path.name}
    if cuda:
        busy = sum(getattr(avg, device_key, 0.0) for avg in averages) / 1e6 / iterations
        result["gpu_kernel_s_per_iteration"] = busy
        result["gpu_busy_fraction"] = busy / s_per_iteration
    return result


# -- environment and report ---------------------------------------------------------------------------------
def environment(device: torch.device) -> dict[str, Any]:
    import importlib.metadata as md

    env: dict[str, Any] = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "device": str(device),
    }
    for name in ("torchrl", "tensordict", "numpy", "kornia", "gymnasium", "omegaconf"):
        with contextlib.suppress(md.PackageNotFoundError):
            env[name] = md.version(name)
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        env.update(
            {
                "gpu": props.name,
                "gpu_memory_gib": props.total_memory / 2**30,
                "multiprocessors": props.multi_processor_count,
                "capability": f"{props.major}.{props.minor}",
                "cuda": torch.version.cuda,
                "cudnn": torch.backends.cudnn.version(),
            }
        )
    return env


def imported_distributions() -> list[str]:
    """Distributions of the top-level modules imported since this script started (the run's needs)."""
    import importlib.metadata as md

    by_module = md.packages_distributions()
    new = {name.split(".")[0] for name in set(sys.modules) - _MODULES_AT_START}
    return sorted({dist for module in new for dist in by_module.get(module, [])})


def _fmt(value: Any, spec: str = ".3g", unit: str = "") -> str:
    return "-" if value is None else f"{value:{spec}}{unit}"


def _per(values: dict[str, Any], keys: tuple[str, ...], spec: str) -> str:
    return " / ".join(_fmt(values.get(key), spec) for key in keys)


def markdown(data: dict[str, Any]) -> str:
    """The short table of ``gpu_run.md`` (whatever phases ``data`` holds so far)."""
    env, phases, summary = data.get("env", {}), data.get("phases", {}), data.get("summary", {})
    train, generated = phases.get("train", {}), phases.get("data", {})
    per_task = _per(train.get("median_s", {}), TASKS, ".4f")
    goal_met = summary.get("goal_met", "-")
    rows = [
        (
            "seconds per iteration, median over windows (D_e / D_ca medians)",
            f"{_fmt(summary.get('s_per_iteration'), '.4f')} ({per_task})",
        ),
        ("iterations/s", _fmt(summary.get("iterations_per_s"), ".2f")),
        (
            f"projected 10,000 iterations (goal <= {GOAL_10K_S // 60} min)",
            f"{_fmt(summary.get('projected_10k_min'), '.1f', ' min')} (goal met: {goal_met})",
        ),
        (
            "achieved TFLOP/s (FLOPs of one D_e + one D_ca iteration)",
            _fmt(summary.get("achieved_tflops"), ".2f"),
        ),
        ("bf16 matmul rate, same run", _fmt(summary.get("peak_tflops"), ".1f", " TFLOP/s")),
        ("MFU (achieved / matmul rate)", _fmt(summary.get("mfu"), ".2%")),
        ("GPU busy (profiled kernel time / iteration time)", _fmt(summary.get("gpu_busy_fraction"), ".1%")),
        ("GPU memory peak", _fmt(summary.get("gpu_memory_peak_gib"), ".2f", " GiB")),
        (
            "frames per iteration (D_e / D_ca; valid steps + 2 x pairs)",
            _per(train.get("frames_per_iteration", {}), TASKS, ".0f"),
        ),
        (
            "mean s per phase (sample wait / forward+backward / optimizer)",
            _per(train.get("phases_s", {}), ("sample", "forward_backward", "optimizer"), ".4f"),
        ),
    ]
    if generated:
        gib = generated.get("bytes", 0) / 2**30
        reused = ", ".join(generated.get("reused", [])) or "none"
        rows.append(
            (
                f"synthetic data: {generated.get('images')} images, {gib:.2f} GiB, "
                f"{generated.get('workers')} workers (reused: {reused})",
                f"{_fmt(generated.get('total_s'), '.1f', ' s')}; paper scale projected "
                f"{_fmt(generated.get('paper_scale_projected_s'), '.0f', ' s')}",
            )
        )
    lines = [
        f"# gpu_run: {env.get('gpu', env.get('device', '?'))}, torch {env.get('torch', '?')} "
        f"({data.get('status')}, {data.get('elapsed_s', 0):.0f} s of a {data.get('budget_s')} s budget)",
        "",
        "| figure | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in rows),
    ]
    variants = phases.get("variants", {})
    if variants:
        lines += ["", "| variant | s/iteration | x main | projected 10k | TFLOP/s |", "|---|---|---|---|---|"]
        main = summary.get("s_per_iteration")
        for name, result in variants.items():
            s = result.get("s_per_iteration")
            if s is None:
                lines.append(f"| {name} | {result.get('error', '-')} | | | |")
                continue
            lines.append(
                f"| {name} | {s:.4f} | {_fmt(s / main if main else None, '.2f', 'x')} | "
                f"{s * ITERATIONS_10K / 60:.1f} min | {_fmt(result.get('achieved_tflops'), '.2f')} |"
            )
    if data.get("errors"):
        lines += ["", "Errors:", *(f"- {error}" for error in data["errors"])]
    return "\n".join(lines) + "\n"


def summarise(data: dict[str, Any]) -> None:
    """``data["summary"]``: the headline figures of the main configuration against the matmul peak."""
    train, peak = data["phases"].get("train", {}), data["phases"].get("peak", {})
    s = train.get("s_per_iteration")
    summary: dict[str, Any] = {
        "s_per_iteration": s,
        "iterations_per_s": train.get("iterations_per_s"),
        "projected_10k_s": train.get("projected_10k_s"),
        "projected_10k_min": s * ITERATIONS_10K / 60 if s else None,
        "goal_10k_s": GOAL_10K_S,
        "goal_met": (s * ITERATIONS_10K <= GOAL_10K_S) if s else None,
        "peak_tflops": peak.get("tflops"),
        "achieved_tflops": train.get("achieved_tflops"),
        "mfu": None,
        "gpu_memory_peak_gib": train.get("gpu_memory_peak_gib"),
        "gpu_busy_fraction": train.get("profile", {}).get("gpu_busy_fraction"),
    }
    if summary["achieved_tflops"] and summary["peak_tflops"]:
        summary["mfu"] = summary["achieved_tflops"] / summary["peak_tflops"]
    data["summary"] = summary


# -- main ---------------------------------------------------------------------------------------------------
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", "gpu_run_out")))
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "navformer_gpu_data")
    parser.add_argument("--device", default="cuda", help="cuda | cuda:N | cpu (default cuda)")
    parser.add_argument("--tiny", action="store_true", help="tiny data, model and counts (CPU test)")
    parser.add_argument("--budget-s", type=float, default=420.0, help="the whole run's time limit")
    parser.add_argument("--data-scale", type=float, default=0.1, help="fraction of the paper's counts")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="data-writing processes")
    parser.add_argument("--warmup", type=int, default=6, help="untimed iterations first (even)")
    parser.add_argument("--iterations", type=int, default=100, help="timed iterations of the main run")
    parser.add_argument("--window", type=int, default=10, help="iterations per timing window (even)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated names, or none")
    parser.add_argument("--no-profile", action="store_true")
    args = parser.parse_args(argv)
    problems = []
    if args.device != "cpu" and not args.device.startswith("cuda"):
        problems.append(f"--device {args.device!r}: expected cuda, cuda:N or cpu")
    for name in ("warmup", "window"):
        value = getattr(args, name)
        if value < 2 or value % 2:
            problems.append(
                f"--{name} {value}: expected an even number >= 2 (D_e and D_ca iterations alternate)"
            )
    if args.iterations < args.window:
        problems.append(
            f"--iterations {args.iterations}: expected at least one window (--window {args.window})"
        )
    if not 0 < args.data_scale <= 1:
        problems.append(f"--data-scale {args.data_scale}: expected a fraction in (0, 1]")
    if args.budget_s <= 0 or args.workers < 1:
        problems.append(f"--budget-s {args.budget_s} / --workers {args.workers}: expected positive numbers")
    names = [] if args.variants == "none" else [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        problems.append(f"--variants {unknown}: expected names among {list(VARIANTS)} or none")
    if problems:
        parser.error("; ".join(problems))
    args.variant_names = names
    return args


def _interrupt(signum: int, frame: object) -> None:
    raise Interrupted(signal.Signals(signum).name)


def run_variants(
    args: argparse.Namespace, scale: Scale, paths: dict[str, Path], tmp: Path, report: Report
) -> None:
    """Each of ``args.variant_names`` that fits the budget: a fresh trainer, half the main iterations."""
    phases, budget = report.data["phases"], report.budget
    main = phases["train"]
    variant_iterations = max(scale.iterations // 2 // scale.window, 1) * scale.window
    # about a build plus its iterations at up to 2x the main run's time, plus its data when new
    per_variant = main["build_s"] + 2 * main["s_per_iteration"] * (scale.warmup + 2 + variant_iterations)
    for index, name in enumerate(args.variant_names):
        needed = per_variant + 20 + (phases["data"]["total_s"] if name == WIDE_VARIANT else 0)
        if budget.left() < needed:
            phases["variants"][name] = {
                "error": f"skipped: {budget.left():.0f} s left, ~{needed:.0f} s needed"
            }
            continue
        print(f"[{budget.elapsed():6.1f}s] variant: {name}", flush=True)
        result: dict[str, Any] = {}
        try:
            variant_paths = paths
            if name == WIDE_VARIANT:
                variant_paths, result["data"] = make_datasets(
                    args.data, scale, scale.wide_lengths, args.workers
                )
            overrides = train_overrides(variant_paths, args.device, scale, tmp / f"variant{index}")
            overrides += VARIANTS[name]
            result.update(measure_training(overrides, variant_iterations, scale, budget, 20.0))
        except Exception as err:
            result["error"] = f"{type(err).__name__}: {err}".splitlines()[0]
            report.error(f"variant {name}", err)
        phases["variants"][name] = result
        report.save()


def run(args: argparse.Namespace) -> dict[str, Any]:
    """All phases; returns the report's data (also written under ``args.out``)."""
    budget = Budget(args.budget_s)
    args.out.mkdir(parents=True, exist_ok=True)
    device = torch.device(args.device)
    scale = TINY if args.tiny else paper_scale(args.data_scale, args.iterations, args.window, args.warmup)
    report = Report(args.out, budget)
    report.data.update(
        {
            "status": "running",
            "budget_s": args.budget_s,
            "tiny": bool(args.tiny),
            "scale": asdict(scale),
            "goal": f"{ITERATIONS_10K} iterations in <= {GOAL_10K_S} s",
            "errors": [],
            "phases": {},
        }
    )
    if device.type == "cuda" and not torch.cuda.is_available():
        report.data["status"] = "failed"
        report.data["errors"].append(f"--device {args.device}: torch {torch.__version__} sees no CUDA device")
        report.save()
        return report.data
    report.save()
    phases = report.data["phases"]
    status = "complete"
    try:
        print(f"[{budget.elapsed():6.1f}s] data: {scale.counts} under {args.data}", flush=True)
        paths, phases["data"] = make_datasets(args.data, scale, scale.lengths, args.workers)
        report.data["env"] = environment(device)  # after the data: it starts CUDA, and the writers fork
        report.save()

        print(f"[{budget.elapsed():6.1f}s] peak: bf16 matmul {scale.matmul_n}^3", flush=True)
        try:
            phases["peak"] = matmul_peak(device, scale.matmul_n)
        except Exception as err:
            report.error("peak", err)
        report.save()

        print(f"[{budget.elapsed():6.1f}s] train: paper configuration, bf16 autocast", flush=True)
        with tempfile.TemporaryDirectory(prefix="gpu_run_") as tmp:
            overrides = train_overrides(paths, args.device, scale, Path(tmp) / "main")
            profile_to = None if args.no_profile else args.out / "profile.txt"
            phases["train"] = measure_training(overrides, scale.iterations, scale, budget, 30.0, profile_to)
            summarise(report.data)
            report.save()
            phases["variants"] = {}
            run_variants(args, scale, paths, Path(tmp), report)
    except Interrupted as why:
        status = f"interrupted ({why})"
    except Exception as err:
        status = "failed"
        report.error("run", err)
    report.data.setdefault("env", {})["imported_distributions"] = imported_distributions()
    report.data["status"] = status
    summarise(report.data)
    report.save()
    return report.data


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGALRM, _interrupt)
    signal.alarm(int(args.budget_s) + 30)
    data = run(args)
    signal.alarm(0)
    print(markdown(data), flush=True)
    return 0 if data["status"] == "complete" and not data["errors"] else 1


if __name__ == "__main__":
    sys.exit(main())
