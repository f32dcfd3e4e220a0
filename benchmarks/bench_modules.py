"""The composed TensorDict actor and the decoder of the parts against a reference commit's modules, same run.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modules.py --reference 7605c27

``--reference`` names a commit whose ``navformer_rl/modules`` is extracted (``git archive``) into a temporary
package and imported beside the working tree's; both models get the same weights (the state-dict names are
mapped with ``upgrade_state_dict``). Measured, alternating reference / current in rounds so that both see
the same machine phases:

- ``train``: the DT loss's forward + backward (``ActionMSELoss``) on a trajectory batch of ``--trajs`` x
  ``--steps`` steps with the training levers (bf16 autocast, channels_last, space-to-depth), the model in
  train mode: the reference wraps its model in one ``TensorDictModule``, the current code runs
  ``make_navformer_actor``'s ``TensorDictSequential`` of the DVE, the causal transformer and the head.
  The rest of an iteration (BYOL, optimisers, sampling) is the same code in both.
- ``step native`` / ``step torch``: one ``IncrementalNavFormer.step`` at batch 1 (the paper model, eval
  mode), with the compiled transformer step and with the torch path, over the first ``--decode-steps`` steps
  of an episode.

Times are process CPU time (run with one thread: the machine's other jobs inflate it least). Prints a
Markdown table: the median ms of each, and the median over the rounds of the current / reference ratio.
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.modules.decoding.native import native_status
from navformer_rl.objectives import ActionMSELoss
from navformer_rl.training.checkpoint import upgrade_state_dict

REPO = Path(__file__).resolve().parents[1]
REFERENCE_PACKAGE = "navformer_reference_modules"
MOVED_MODULES = {"durable": "utils.durable", "checks": "utils.checks", "devices": "utils.devices"}
"""Top-level modules of older commits and where they are now."""
KEYS = ["target_pixels", "pixels", "return_to_go", "action", "step", "mask"]


def import_reference(commit: str, folder: Path):
    """``navformer_rl/modules`` of ``commit`` as the package ``REFERENCE_PACKAGE`` (imports rewritten)."""
    archive = subprocess.run(
        ["git", "archive", commit, "navformer_rl/modules"], cwd=REPO, capture_output=True, check=True
    ).stdout
    archive_path = folder / "modules.tar"
    archive_path.write_bytes(archive)
    with tarfile.open(archive_path) as tar:
        tar.extractall(folder, filter="data")
    package = folder / REFERENCE_PACKAGE
    (folder / "navformer_rl" / "modules").rename(package)
    for source in package.rglob("*.py"):
        text = source.read_text().replace("navformer_rl.modules", REFERENCE_PACKAGE)
        for (
            old,
            new,
        ) in MOVED_MODULES.items():  # package modules the reference imports, at their current place
            text = text.replace(f"navformer_rl.{old}", f"navformer_rl.{new}")
            text = text.replace(
                f"from navformer_rl import {old}", f"from navformer_rl.{new.rpartition('.')[0]} import {old}"
            )
        source.write_text(text)
    sys.path.insert(0, str(folder))
    return importlib.import_module(REFERENCE_PACKAGE)


def trajectory_batch(trajs: int, steps: int, seed: int = 0) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "target_pixels": torch.randint(0, 256, (trajs, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "pixels": torch.randint(0, 256, (trajs, steps, 84, 84, 3), dtype=torch.uint8, generator=gen),
            "return_to_go": torch.rand(trajs, steps, 1, generator=gen),
            "action": torch.rand(trajs, steps, 2, generator=gen) * 2 - 1,
            "step": torch.arange(steps).expand(trajs, steps).clone(),
            "mask": torch.ones(trajs, steps, dtype=torch.bool),
        },
        batch_size=[trajs],
    )


def paired_models(reference, config_changes: dict) -> tuple[torch.nn.Module, NavFormerModel]:
    """A reference model and a current one with the same weights."""
    torch.manual_seed(0)
    current = NavFormerModel(NavFormerConfig(**config_changes))
    old = reference.NavFormerModel(reference.NavFormerConfig(**config_changes))
    old_names = list(old.state_dict())
    old_name = dict(zip(upgrade_state_dict(old.state_dict()), old_names, strict=True))
    old.load_state_dict({old_name[name]: value for name, value in current.state_dict().items()})
    return old, current


def time_once(fn) -> float:
    """The process CPU time of ``fn()`` in ms (with one thread,
    what the machine's other jobs inflate least)."""
    start = time.process_time()
    fn()
    return (time.process_time() - start) * 1e3


def alternate(functions: dict[str, callable], rounds: int, batch: int = 1) -> dict[str, float]:
    """Per function, the median CPU ms of a call over ``rounds`` rounds, and ``"ratio"``: the median over
    the rounds of current / reference. Each round times ``batch`` calls of each function, in alternating
    order (after a warm-up)."""
    for fn in functions.values():
        fn()
    samples = {name: [] for name in functions}
    names = list(functions)
    for round_index in range(rounds):
        for name in names if round_index % 2 == 0 else names[::-1]:
            fn = functions[name]
            samples[name].append(time_once(lambda fn=fn: [fn() for _ in range(batch)]) / batch)
    ratios = [current / reference for reference, current in zip(samples["reference"], samples["current"])]
    return {
        **{name: statistics.median(values) for name, values in samples.items()},
        "ratio": statistics.median(ratios),
    }


def train_functions(reference, trajs: int, steps: int) -> dict[str, callable]:
    levers = {"autocast_dtype": "bfloat16", "channels_last": True, "space_to_depth": True}
    old, current = paired_models(reference, levers)
    losses = {
        "reference": ActionMSELoss(TensorDictModule(old.train(), in_keys=KEYS, out_keys=["action_pred"])),
        "current": ActionMSELoss(make_navformer_actor(current.train())),
    }
    batch = trajectory_batch(trajs, steps)

    def forward_backward(loss):
        def run():
            torch.manual_seed(1)  # the same dropout masks in both
            loss.zero_grad(set_to_none=True)
            loss(batch)["loss_dt"].backward()

        return run

    return {name: forward_backward(loss) for name, loss in losses.items()}


def step_functions(reference, native: bool, decode_steps: int) -> dict[str, callable]:
    old, current = paired_models(reference, {})
    decoders = {
        "reference": reference.IncrementalNavFormer(old.eval(), 1, native=native),
        "current": IncrementalNavFormer(current.eval(), 1, native=native),
    }
    gen = torch.Generator().manual_seed(2)
    frames = torch.randint(0, 256, (decode_steps, 1, 84, 84, 3), dtype=torch.uint8, generator=gen)
    target = frames[0]
    counters = dict.fromkeys(decoders, 0)

    def step(name):
        decoder = decoders[name]

        def run():
            t = counters[name] % decode_steps
            if t == 0:
                decoder.reset()
            counters[name] += 1
            with torch.inference_mode():
                decoder.step(target, frames[t], torch.ones(1, 1), torch.zeros(1, 2))

        return run

    return {name: step(name) for name in decoders}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--reference", default="7605c27", help="commit of the reference modules")
    parser.add_argument("--trajs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=98)
    parser.add_argument("--train-rounds", type=int, default=7)
    parser.add_argument("--decode-steps", type=int, default=200)
    parser.add_argument("--step-rounds", type=int, default=100, help="rounds of 20 steps")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        reference = import_reference(args.reference, Path(folder))
        rows = {"train": alternate(train_functions(reference, args.trajs, args.steps), args.train_rounds)}
        paths = [True, False] if native_status().available else [False]
        for native in paths:
            functions = step_functions(reference, native, args.decode_steps)
            rows[f"step {'native' if native else 'torch'}"] = alternate(functions, args.step_rounds, batch=20)
    print(f"| what | reference {args.reference} (CPU ms) | current (CPU ms) | current / reference |")
    print("|---|---|---|---|")
    for name, times in rows.items():
        print(f"| {name} | {times['reference']:.3f} | {times['current']:.3f} | {times['ratio']:.3f} |")


if __name__ == "__main__":
    main()
