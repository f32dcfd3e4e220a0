"""Training-iteration throughput of NavFormer at the paper's batch shapes, against the matmul floor.

One paper iteration (§VI) = the DT loss on one trajectory batch (alternately 25 x 98 steps from D_e and
150 x 63 steps from D_ca) + BYOL on 512 image pairs for both encoders (eq. 11), backward, AdamW, the EMA
update. The script times, per configuration (median over ``--repeats``, after one warm-up):

- ``aug``: the BYOL augmentations alone (3 x 512 images, ``BYOLAugmentation``);
- ``A`` / ``B``: a full iteration with batch A / B (augmentation included); ``mean`` = (A + B) / 2;
- frames/s = trajectory frames per second over A and B; GFLOP/s = counted FLOPs / time, and the
  fraction of the large-matmul floor (fp32 and bf16), measured in the same run just before and after each
  configuration (the mean of the two), since the load of a shared machine drifts.

FLOPs: ``torch.utils.flop_counter``'s formulas on one iteration of each kind (convolutions, linears, ...)
plus the causal attention counted analytically (the counter does not see CPU SDPA): forward
``2 * B * H * L^2 * d_head`` per block (the causal half), backward twice that. Counted separately with
``detach_encoders`` (no encoder backward in the DT loss), so GFLOP/s is the work each configuration executes.

Configurations (levers are ``NavFormerConfig`` / ``BYOLLoss`` options the training loop can set):
``fp32`` (NCHW, one chunk), ``bf16`` (autocast bfloat16 + channels_last), ``bf16_mb`` (+ encoder
micro-batches of ``--micro-batch``), ``bf16_mb_s2d`` (+ ``space_to_depth`` first convolution: the
training default; it also takes the last convolution's weight gradient as an im2col matmul, which
``bf16_mb_s2d_onednn_w`` leaves to oneDNN), ``bf16_mb_s2d_detach`` (+ ``detach_encoders``: the DT loss does
not back-propagate into the encoders).

Usage: ``OMP_NUM_THREADS=2 python benchmarks/bench_train_step.py [--configs fp32 bf16_mb] [--repeats 3]``
(``--device cuda`` on a GPU machine: everything, the matmul floors included, runs there; times are
synchronised) (``GLIBC_TUNABLES=glibc.malloc.hugetlb=1`` in the environment avoids page faults on big tensors,
and ``--malloc keep`` (default: ``navformer_rl.utils.allocator.keep_freed_memory``, as ``navformer train``
does) keeps freed big blocks for reuse; ``--malloc default`` measures glibc's own behaviour;
``--min-valid 0.5`` right-pads the trajectory batches, whose padded frames the encoders skip.)
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.flop_counter import flop_registry
from torchrl.objectives import SoftUpdate

from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionMSELoss, BYOLLoss, joint_parameters
from navformer_rl.utils.allocator import keep_freed_memory

CONFIGS = {
    "fp32": {"channels_last": False, "space_to_depth": False},
    "bf16": {"autocast_dtype": "bfloat16", "space_to_depth": False},
    "bf16_mb": {"autocast_dtype": "bfloat16", "encoder_micro_batch": "MB", "space_to_depth": False},
    "bf16_mb_detach": {
        "autocast_dtype": "bfloat16",
        "encoder_micro_batch": "MB",
        "detach_encoders": True,
        "space_to_depth": False,
    },
    "bf16_mb_s2d": {"autocast_dtype": "bfloat16", "encoder_micro_batch": "MB"},
    "bf16_mb_s2d_onednn_w": {
        "autocast_dtype": "bfloat16",
        "encoder_micro_batch": "MB",
        "matmul_weight_grad": False,
    },
    "bf16_mb_s2d_detach": {
        "autocast_dtype": "bfloat16",
        "encoder_micro_batch": "MB",
        "detach_encoders": True,
    },
    "fp32_mb": {"encoder_micro_batch": "MB"},
}


def synchronize(device: torch.device | str) -> None:
    """Wait for queued CUDA work (a no-op on CPU), so wall-clock times cover the computation."""
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def median_ms(fn, repeats: int, device: torch.device | str = "cpu") -> float:
    fn()
    synchronize(device)
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        synchronize(device)
        samples.append((time.perf_counter() - start) * 1e3)
    return statistics.median(samples)


def matmul_gflops(dtype: torch.dtype, device: torch.device, n: int = 2048, repeats: int = 5) -> float:
    a, b = torch.randn(n, n, device=device).to(dtype), torch.randn(n, n, device=device).to(dtype)
    return 2 * n**3 / median_ms(lambda: a @ b, repeats, device) / 1e6


def trajectory_batch(n: int, steps: int, seed: int, min_valid: float = 1.0) -> TensorDict:
    """Right-padded trajectories: each keeps a uniform number of valid steps in [min_valid * steps, steps]."""
    gen = torch.Generator().manual_seed(seed)
    low = max(1, round(min_valid * steps))
    lengths = torch.randint(low, steps + 1, (n, 1), generator=gen)
    return TensorDict(
        {
            "target_pixels": torch.randint(0, 256, (n, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "pixels": torch.randint(0, 256, (n, steps, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "return_to_go": torch.ones(n, steps, 1),
            "action": torch.rand(n, steps, 2, generator=gen) * 2 - 1,
            "step": torch.arange(steps).expand(n, steps).clone(),
            "mask": torch.arange(steps).expand(n, steps) < lengths,
        },
        batch_size=[n],
    )


def pair_batch(n: int, seed: int) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    shape = (n, 84, 84, 3)
    return TensorDict(
        {
            "pixels_static": torch.randint(0, 256, shape, dtype=torch.uint8, generator=gen),
            "pixels_dynamic": torch.randint(0, 256, shape, dtype=torch.uint8, generator=gen),
        },
        batch_size=[n],
    )


class Trainer:
    """Model, both losses, one AdamW over their joint parameters and the EMA updater (the paper's loop)."""

    def __init__(
        self, config: NavFormerConfig, device: torch.device | str = "cpu", matmul_weight_grad: bool = True
    ) -> None:
        torch.manual_seed(0)
        self.model = NavFormerModel(config).to(device)
        for _, encoder in self.model.observation_encoders():
            if hasattr(encoder, "matmul_weight_grad"):
                encoder.matmul_weight_grad = matmul_weight_grad
        self.dt_loss = ActionMSELoss(make_navformer_actor(self.model))
        self.byol_loss = BYOLLoss(
            self.model.static_encoder, self.model.general_encoder, autocast_dtype=config.autocast_dtype
        )
        self.updater = SoftUpdate(self.byol_loss, eps=0.996)
        self.optimizer = torch.optim.AdamW(
            joint_parameters(self.dt_loss, self.byol_loss), lr=2e-4, weight_decay=1e-4
        )

    def iteration(self, trajectories: TensorDict, pairs: TensorDict) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        loss = self.dt_loss(trajectories)["loss_dt"] + self.byol_loss(pairs)["loss_byol"]
        loss.backward()
        self.optimizer.step()
        self.updater.step()


class CountFlops(TorchDispatchMode):
    """``torch.utils.flop_counter``'s per-op formulas without its module tracker (which trips on
    TensorDictParams)."""

    def __init__(self) -> None:
        super().__init__()
        self.total = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        out = func(*args, **kwargs)
        formula = flop_registry.get(func._overloadpacket)
        if formula is not None:
            self.total += formula(*args, **kwargs, out_val=out)
        return out


def attention_flops(config: NavFormerConfig, n: int, steps: int) -> float:
    length = config.tokens_per_step * steps
    forward = 2 * n * config.n_heads * length**2 * config.d_head * config.n_blocks
    return 3 * forward


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--configs", nargs="+", default=["fp32", "bf16", "bf16_mb", "bf16_mb_s2d", "bf16_mb_s2d_detach"]
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--micro-batch", type=int, default=512)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--device", default="cpu", help="cpu or cuda (times are synchronised)")
    parser.add_argument("--batch-a", type=int, nargs=2, default=[25, 98], metavar=("N", "T"))
    parser.add_argument("--batch-b", type=int, nargs=2, default=[150, 63], metavar=("N", "T"))
    parser.add_argument("--pairs", type=int, default=512)
    parser.add_argument(
        "--min-valid",
        type=float,
        default=1.0,
        help=(
            "trajectories keep U[min_valid * T, T] valid steps (1.0: no padding); "
            "padded frames are not encoded"
        ),
    )
    parser.add_argument(
        "--malloc",
        choices=["keep", "default"],
        default="keep",
        help="keep: glibc keeps freed big blocks (navformer train's keep_freed_memory); default: glibc's own",
    )
    args = parser.parse_args()
    malloc_kept = args.malloc == "keep" and keep_freed_memory()
    if args.threads:
        torch.set_num_threads(args.threads)
    unknown = set(args.configs) - set(CONFIGS)
    if unknown:
        raise SystemExit(f"unknown configs {sorted(unknown)}: expected some of {sorted(CONFIGS)}")

    device = torch.device(args.device)
    batch_a = trajectory_batch(*args.batch_a, seed=1, min_valid=args.min_valid).to(device)
    batch_b = trajectory_batch(*args.batch_b, seed=2, min_valid=args.min_valid).to(device)
    pairs = pair_batch(args.pairs, seed=3).to(device)
    frames_a, frames_b = args.batch_a[0] * args.batch_a[1], args.batch_b[0] * args.batch_b[1]

    fp32_floor, bf16_floor = matmul_gflops(torch.float32, device), matmul_gflops(torch.bfloat16, device)
    print(
        f"# torch {torch.__version__}, device {device}, threads {torch.get_num_threads()}, "
        f"load average {os.getloadavg()[0]:.2f}, "
        f"GLIBC_TUNABLES={os.environ.get('GLIBC_TUNABLES', '')!r}, malloc keeps freed memory: {malloc_kept}"
    )
    valid = (batch_a["mask"].float().mean().item(), batch_b["mask"].float().mean().item())
    print(f"# valid fraction of trajectory steps: A {valid[0]:.2f}, B {valid[1]:.2f}")
    print(f"# matmul floor (2048^3): fp32 {fp32_floor:.0f} GFLOP/s, bf16 {bf16_floor:.0f} GFLOP/s")

    def count_flops(config: NavFormerConfig) -> dict[str, float]:
        """FLOPs of one iteration A and B (fp32 ops; autocast runs the same ops in bf16)."""
        trainer, flops = Trainer(config, device), {}
        for kind, batch, n_t in (("A", batch_a, args.batch_a), ("B", batch_b, args.batch_b)):
            with CountFlops() as counter:
                trainer.iteration(batch, pairs)
            flops[kind] = counter.total + attention_flops(config, *n_t)
        return flops

    flops_by_detach = {False: count_flops(NavFormerConfig())}
    paper = flops_by_detach[False]
    paper_mean = (paper["A"] + paper["B"]) / 2
    print(
        f"# counted FLOPs per iteration: A {paper['A'] / 1e9:.0f} G, B {paper['B'] / 1e9:.0f} G, "
        f"mean {paper_mean / 1e9:.0f} G; floors for the mean iteration: fp32 "
        f"{paper_mean / fp32_floor / 1e9:.2f} s, bf16 {paper_mean / bf16_floor / 1e9:.2f} s"
    )
    print(
        "| config | aug ms | A ms | B ms | mean s/iter | frames/s | GFLOP/s | fp32 / bf16 floor GFLOP/s "
        "| % fp32 floor | % bf16 floor | 10k iters h |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.configs:
        options = {k: (args.micro_batch if v == "MB" else v) for k, v in CONFIGS[name].items()}
        matmul_weight_grad = options.pop("matmul_weight_grad", True)
        trainer = Trainer(NavFormerConfig(**options), device, matmul_weight_grad)
        aug = trainer.byol_loss.augmentation
        aug_ms = median_ms(
            lambda aug=aug: [aug(pairs["pixels_dynamic"]) for _ in range(3)], args.repeats, device
        )
        a_ms = median_ms(lambda trainer=trainer: trainer.iteration(batch_a, pairs), args.repeats, device)
        b_ms = median_ms(lambda trainer=trainer: trainer.iteration(batch_b, pairs), args.repeats, device)
        mean_s = (a_ms + b_ms) / 2e3
        detach = bool(options.get("detach_encoders", False))
        if detach not in flops_by_detach:
            flops_by_detach[detach] = count_flops(NavFormerConfig(detach_encoders=detach))
        flops = flops_by_detach[detach]
        gflops = (flops["A"] + flops["B"]) / 2 / mean_s / 1e9  # FLOPs this configuration really executes
        # floors again right after this configuration: on a shared machine the load drifts
        fp32_after, bf16_after = matmul_gflops(torch.float32, device), matmul_gflops(torch.bfloat16, device)
        fp32_now, bf16_now = (fp32_floor + fp32_after) / 2, (bf16_floor + bf16_after) / 2
        fp32_floor, bf16_floor = fp32_after, bf16_after
        print(
            f"| {name} | {aug_ms:.0f} | {a_ms:.0f} | {b_ms:.0f} | {mean_s:.2f} | "
            f"{(frames_a + frames_b) / (2 * mean_s):.0f} | {gflops:.0f} | {fp32_now:.0f} / {bf16_now:.0f} | "
            f"{100 * gflops / fp32_now:.0f} % | {100 * gflops / bf16_now:.0f} % | "
            f"{mean_s * 1e4 / 3600:.1f} |",
            flush=True,
        )
        del trainer


if __name__ == "__main__":
    main()
