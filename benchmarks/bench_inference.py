"""Per-step NavFormer inference latency: KV-cache step vs full recompute (CPU by default).

For each batch size (robots) and episode position T the script measures, with the paper model in eval mode
and under ``torch.no_grad``:

- ``kv``: one ``IncrementalNavFormer.step`` at timestep T (encoding the new frame with f_s and f_g as one
  fused stack, the transformer on the 4 new tokens against the cache, the THSC head); median over
  ``--steps`` consecutive steps. Timed for each transformer path of ``--paths``: ``native`` (the compiled
  kernel, ``NativeTransformerStep``, the default where it builds) and ``torch`` (``TransformerStep``), one
  decoder each, in alternating rounds of a few steps so that both see the same machine phases; ``kv`` is
  the first path's, ``vs torch`` its ratio to the torch path's.
- ``recompute``: the same decision by re-running the transformer over the whole context (target + T steps,
  i.e. 4T tokens), with the frame embeddings of past steps cached and only the new frame encoded; median
  over ``--repeats``.
- ``window``: the recompute of a full 1024-token window (256 steps), the cost of an exact sliding window.
- ``encoders``: the new frame through f_s and f_g alone (``decoder.encode_observations``), median over the
  same number of calls, and ``rest`` = kv - encoders: the token embeddings, the transformer on the 4 new
  tokens and the THSC head. ``rest`` is what the prototype of ``performance.md`` section 4 timed (its
  0.4-0.64 ms at batch 1 leave the encoders out). The encoders are timed back to back, with their weights
  in cache, so ``rest`` also carries the cache misses the step pays for them.

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_inference.py [--threads 1] [--batches 1 6] [--T 50 200 500]
[--paths native torch]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel
from navformer_rl.modules.decoding.native import native_status


def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` calls (after one warm-up; CUDA synchronised)."""
    fn()
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    sync()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        samples.append((time.perf_counter() - start) * 1e3)
    return statistics.median(samples)


def random_frames(*shape: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (*shape, 84, 84, 3), dtype=torch.uint8, generator=gen)


def recompute_step(
    decoder: IncrementalNavFormer, cached: dict[str, torch.Tensor], pixels: torch.Tensor, steps: int
):
    """Decide the action at step ``steps - 1`` by running the transformer over the whole context
    (the new frame is encoded exactly as the KV step encodes it)."""
    model = decoder.model
    tps, embedding = model.config.tokens_per_step, model.transformer.tokens
    obs = torch.cat([cached["obs"][:, : steps - 1], decoder.encode_observations(pixels)[:, None]], dim=1)
    tokens = embedding.step_tokens(
        list(obs.unbind(2)), cached["rtg"][:, :steps], cached["action"][:, :steps], cached["step"][:, :steps]
    )
    batch = tokens.shape[0]
    sequence = torch.cat([cached["target"][:, None], tokens.reshape(batch, steps * tps, -1)[:, :-1]], dim=1)
    hidden, _ = model.transformer.gpt(embedding.prepare(sequence))
    named = {"target": hidden[:, :1], "observation": hidden[:, -1:]}
    return model.head(*(named[name] for name in model.head.reads))[:, 0]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 6])
    parser.add_argument("--T", type=int, nargs="+", default=[50, 200, 500])
    parser.add_argument("--steps", type=int, default=20, help="KV-cache steps timed at each T")
    parser.add_argument("--repeats", type=int, default=5, help="repeats of each recompute")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--paths", nargs="+", choices=("native", "torch"), default=["native", "torch"],
        help="transformer paths to time (the first one fills the kv, encoders and ratio columns)",
    )  # fmt: skip
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig()).to(device).eval()
    window = model.config.window_steps
    print(f"# torch {torch.__version__}, device {device}, threads {torch.get_num_threads()}, "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    paths = list(dict.fromkeys(args.paths))
    status = native_status()
    if "native" in paths and (not status.available or device.type != "cpu"):
        why = status.reason if not status.available else f"it runs on the CPU, not {device}"
        print(f"# native kernel unavailable ({why}): timing the torch path only")
        paths = ["torch"]
    other = "torch" if paths[0] != "torch" and "torch" in paths else None
    print(f"# paths: {', '.join(paths)}; native kernel: {status.reason}")
    print(
        "| robots | T | tokens | KV step ms | ms / robot-step | vs torch | of which encoders ms | rest ms "
        "| recompute ms | speed-up | window recompute ms | window / KV |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    rounds = 4
    with torch.no_grad():
        for batch in args.batches:
            window_ms = None
            length = max(max(args.T) + args.steps, window)  # the window recompute reads `window` steps
            frames = random_frames(batch, 8, seed=batch).to(device)  # cycle 8 frames: content is irrelevant
            target = random_frames(batch, seed=99).to(device)
            cached = {
                "target": model.transformer.tokens.target_token(model.dve.encode_target(target)),
                "obs": model.dve.encode_observations(frames)[:, torch.arange(length) % 8],
                "rtg": torch.ones(batch, length, 1, device=device),
                "action": torch.rand(batch, length, 2, device=device) * 2 - 1,
                "step": torch.arange(length, device=device).clamp(max=511).expand(batch, -1),
            }
            rtg = torch.ones(batch, 1, device=device)
            runs = {
                path: [IncrementalNavFormer(model, batch, device=device, native=path == "native"),
                       torch.zeros(batch, 2, device=device)]
                for path in paths
            }  # fmt: skip

            def advance(path: str, runs=runs, frames=frames, target=target, rtg=rtg) -> float:
                """One step of ``path``'s decoder; its wall time in ms."""
                run = runs[path]
                pixels = frames[:, int(run[0].steps_done[0]) % 8]
                start = time.perf_counter()
                run[1] = run[0].step(target, pixels, rtg, run[1])
                return (time.perf_counter() - start) * 1e3

            for t in sorted(args.T):
                for path in paths:  # advance each episode to step T - 1
                    while int(runs[path][0].steps_done[0]) < t - 1:
                        advance(path)
                samples = {path: [] for path in paths}
                for _ in range(rounds):  # alternate the paths so both see the same machine phases
                    for path in paths:
                        samples[path] += [advance(path) for _ in range(-(-args.steps // rounds))]
                kv_ms = {path: statistics.median(samples[path]) for path in paths}
                decoder = runs[paths[0]][0]
                pixels = frames[:, t % 8]
                encoder_ms = timed(
                    lambda pixels=pixels, decoder=decoder: decoder.encode_observations(pixels), args.steps
                )
                pixels = frames[:, (t - 1) % 8]
                recompute_ms = timed(
                    lambda t=t, pixels=pixels, cached=cached, decoder=decoder: recompute_step(
                        decoder, cached, pixels, t
                    ),
                    args.repeats,
                )
                if window_ms is None:
                    window_ms = timed(
                        lambda pixels=pixels, cached=cached, decoder=decoder: recompute_step(
                            decoder, cached, pixels, window
                        ),
                        args.repeats,
                    )
                tps = model.config.tokens_per_step
                kv = kv_ms[paths[0]]
                ratio = f"{kv / kv_ms[other]:.2f} ({kv_ms[other]:.3f} ms)" if other else "-"
                print(
                    f"| {batch} | {t} | {tps * t} | {kv:.3f} | {kv / batch:.3f} | {ratio} | {encoder_ms:.3f} "
                    f"| {kv - encoder_ms:.3f} | {recompute_ms:.1f} | "
                    f"{recompute_ms / kv:.0f}x | {window_ms:.1f} | {window_ms / kv:.0f}x |"
                )


if __name__ == "__main__":
    main()
