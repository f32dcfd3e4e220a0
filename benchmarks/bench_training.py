"""Seconds per training iteration of the real loop (``Trainer.step``) at the paper's batch shapes.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_training.py --data /tmp/nf_bench --repeats 2

Builds (once) synthetic datasets in the real on-disk format with the paper's mean trajectory lengths
(D_e: 98 steps, drawn in [90, 106]; D_ca: 63 steps, in [55, 71]; D_ssl pairs), then runs each configuration in
its own process (``GLIBC_TUNABLES`` must be set before the process starts): warm-up iterations, then
``repeats`` pairs of (D_e, D_ca) iterations, each with the 512-pair BYOL batch. Reports the median seconds of
a D_e and of a D_ca iteration, their mean (iterations alternate), the projection to 10,000 iterations, the
FLOPs of one iteration (``torch.utils.flop_counter``: dense layers and convolutions; attention is not
counted, so the achieved rate is a lower bound) and, as the reference measured in the same run, the
GFLOP/s of a large fp32 and bf16 matmul. Prints a Markdown table and writes JSON next to the data.

Every configuration keeps glibc's freed memory (``keep_freed_memory=true``, ``navformer train``'s default)
unless its overrides say otherwise ("bf16 levers + glibc's own malloc" measures that lever).

On a shared machine wall-clock times are inflated by other processes; the process CPU time of each iteration
(``time.process_time``) is reported beside it and, with one thread, is the better estimate of the cost.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

CONFIGS: dict[str, dict] = {
    "fp32": {"overrides": [], "hugetlb": False},
    "fp32 + hugetlb": {"overrides": [], "hugetlb": True},
    "bf16 + channels_last + micro-batch 512 + hugetlb": {
        "overrides": [
            "model.autocast_dtype=bfloat16",
            "model.channels_last=true",
            "model.encoder_micro_batch=512",
        ],
        "hugetlb": True,
    },
    "bf16 levers + glibc's own malloc (keep_freed_memory=false)": {
        "overrides": [
            "model.autocast_dtype=bfloat16",
            "model.channels_last=true",
            "model.encoder_micro_batch=512",
            "keep_freed_memory=false",
        ],
        "hugetlb": True,
    },
    "bf16 levers without prefetching (data.prefetch=false)": {
        "overrides": [
            "model.autocast_dtype=bfloat16",
            "model.channels_last=true",
            "model.encoder_micro_batch=512",
            "data.prefetch=false",
        ],
        "hugetlb": True,
    },
    "bf16 levers + encoders frozen in L_DT (encoder_training=frozen)": {
        "overrides": [
            "model.autocast_dtype=bfloat16",
            "model.channels_last=true",
            "model.encoder_micro_batch=512",
            "encoder_training=frozen",
        ],
        "hugetlb": True,
    },
}


def make_data(root: Path) -> dict[str, Path]:
    from navformer_rl.data import make_synthetic_dataset

    paths = {"e": root / "e", "ca": root / "ca", "ssl": root / "ssl"}
    specs = {"e": (50, 90, 106), "ca": (300, 55, 71), "ssl": (1024, 1, 1)}
    for kind, path in paths.items():
        if not (path / "metadata.json").is_file():
            n, lo, hi = specs[kind]
            make_synthetic_dataset(path, kind, n, lo, hi, seed=7, items_per_shard=64)
    return paths


def matmul_gflops(dtype: torch.dtype, n: int = 4096, repeats: int = 5) -> float:
    a = torch.randn(n, n).to(dtype)
    b = torch.randn(n, n).to(dtype)
    a @ b
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - start)
    return 2 * n**3 / statistics.median(times) / 1e9


def global_flop_counter():
    """``FlopCounterMode`` without its per-module tracker (whose hooks cannot hash TensorDict-parametrised
    modules); counts the whole step under "Global"."""
    from torch.utils.flop_counter import FlopCounterMode

    class NoModuleTracker:
        parents = {"Global"}

        def __enter__(self):
            return self

        def __exit__(self, *args):
            return None

    counter = FlopCounterMode(display=False)
    counter.mod_tracker = NoModuleTracker()
    return counter


def run_one(data: dict[str, Path], overrides: list[str], repeats: int, out_dir: str) -> dict:
    from navformer_rl.training import build_trainer, load_train_config

    cfg = load_train_config(
        [
            f"data.exploration_path={data['e']}",
            f"data.collision_path={data['ca']}",
            f"data.ssl_path={data['ssl']}",
            "device=cpu",
            "logger.backend=none",
            "logger.progress=false",
            f"output_dir={out_dir}",
            *overrides,
        ]
    )
    trainer = build_trainer(cfg)
    flops = {}
    for task in ("exploration", "collision_avoidance"):  # warm-up pair, FLOPs counted on it
        counter = global_flop_counter()
        with counter:
            metrics = trainer.step()
        assert f"loss_dt_{task}" in metrics
        flops[task] = counter.get_total_flops()
    times: dict[str, list[float]] = {"exploration": [], "collision_avoidance": []}
    cpu_times: dict[str, list[float]] = {"exploration": [], "collision_avoidance": []}
    frames: dict[str, float] = {}
    load = [os.getloadavg()[0]]
    for _ in range(repeats):
        for task in times:
            cpu_start = time.process_time()
            metrics = trainer.step()
            cpu_times[task].append(time.process_time() - cpu_start)
            times[task].append(metrics["iteration_s"])
            frames[task] = metrics["frames"]
    load.append(os.getloadavg()[0])
    trainer.close()
    median = {task: statistics.median(values) for task, values in times.items()}
    cpu_median = {task: statistics.median(values) for task, values in cpu_times.items()}
    mean = (median["exploration"] + median["collision_avoidance"]) / 2
    return {
        "seconds": times,
        "cpu_seconds": cpu_times,
        "median_s": median,
        "cpu_median_s": cpu_median,
        "cpu_mean_s": (cpu_median["exploration"] + cpu_median["collision_avoidance"]) / 2,
        "load_average": load,
        "frames": frames,
        "mean_s": mean,
        "hours_10k": mean * 10_000 / 3600,
        "flops": flops,
        "gflops_per_s": {task: flops[task] / median[task] / 1e9 for task in times},
        "threads": torch.get_num_threads(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "nf_bench")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--configs", default=",".join(CONFIGS), help="comma-separated names of CONFIGS")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    data = make_data(args.data)
    if args.one is not None:
        with tempfile.TemporaryDirectory() as out:
            result = run_one(data, CONFIGS[args.one]["overrides"], args.repeats, out)
        print("RESULT " + json.dumps(result))
        return
    reference = {"fp32": matmul_gflops(torch.float32), "bf16": matmul_gflops(torch.bfloat16)}
    results = {}
    for name in args.configs.split(","):
        env = dict(os.environ)
        if CONFIGS[name]["hugetlb"]:
            env["GLIBC_TUNABLES"] = "glibc.malloc.hugetlb=1"
        cmd = [
            sys.executable,
            __file__,
            "--data",
            str(args.data),
            "--repeats",
            str(args.repeats),
            "--one",
            name,
        ]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
        if proc.returncode != 0 or not line:
            raise RuntimeError(f"{name} failed:\n{proc.stderr[-3000:]}")
        results[name] = json.loads(line[0][len("RESULT ") :])
        print(name, json.dumps(results[name]["median_s"]), flush=True)
    base = results[next(iter(results))]["mean_s"]
    print(f"\nmatmul 4096^3: fp32 {reference['fp32']:.0f} GFLOP/s, bf16 {reference['bf16']:.0f} GFLOP/s")
    base_cpu = results[next(iter(results))]["cpu_mean_s"]
    print(
        "| configuration | D_e iter wall / CPU (s) | D_ca iter wall / CPU (s) | mean wall / CPU (s) | "
        "10k iterations (wall) | GFLOP/s per CPU-s (D_e / D_ca) | speed-up wall / CPU | load avg |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        m, c, f = r["median_s"], r["cpu_median_s"], r["flops"]
        print(
            f"| {name} | {m['exploration']:.2f} / {c['exploration']:.2f} | "
            f"{m['collision_avoidance']:.2f} / {c['collision_avoidance']:.2f} | "
            f"{r['mean_s']:.2f} / {r['cpu_mean_s']:.2f} | {r['hours_10k']:.1f} h | "
            f"{f['exploration'] / c['exploration'] / 1e9:.0f} / "
            f"{f['collision_avoidance'] / c['collision_avoidance'] / 1e9:.0f} | "
            f"{base / r['mean_s']:.2f}x / {base_cpu / r['cpu_mean_s']:.2f}x | "
            f"{r['load_average'][0]:.1f}-{r['load_average'][1]:.1f} |"
        )
    (args.data / "bench_training.json").write_text(
        json.dumps({"reference": reference, "results": results}, indent=2)
    )


if __name__ == "__main__":
    main()
