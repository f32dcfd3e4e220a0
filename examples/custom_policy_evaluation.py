"""Evaluate your own policy in the harness, next to the built-in baselines.

The harness runs any ``TensorDictModuleBase`` that reads the ``MultiRobotNavEnv`` tensordict
(``("agents", "pixels")`` uint8 [A, 84, 84, 3], ``("agents", "target_pixels")``, ...) and writes
``("agents", "action")`` float32 [A, 2] in [-1, 1]. Pass a picklable factory (a module-level function) so
worker processes can build it.

Here: a colour servo that turns toward camera pixels that look like the target's colour and otherwise
wanders. Run: ``.venv/bin/python examples/custom_policy_evaluation.py --out runs/example-eval``
"""

from __future__ import annotations

import argparse

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from navformer_rl.evaluation.episodes import make_protocol_episodes
from navformer_rl.evaluation.harness import evaluate


class ColourServoPolicy(TensorDictModuleBase):
    """Steer toward pixels whose colour is close to the target image's central colour.

    in_keys: ``("agents", "pixels")``, ``("agents", "target_pixels")`` (uint8 [A, 84, 84, 3]).
    out_keys: ``("agents", "action")`` (float32 [A, 2]: linear, angular in [-1, 1]).
    """

    in_keys = [("agents", "pixels"), ("agents", "target_pixels")]
    out_keys = [("agents", "action")]

    def __init__(self, tolerance: float = 60.0) -> None:
        super().__init__()
        self.tolerance = tolerance

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        pixels = tensordict["agents", "pixels"].float()  # [A, H, W, 3]
        target = tensordict["agents", "target_pixels"].float()
        colour = target[:, 36:48, 36:48].reshape(target.shape[0], -1, 3).median(dim=1).values  # [A, 3]
        match = (pixels - colour[:, None, None]).norm(dim=-1) < self.tolerance  # [A, H, W]
        columns = torch.linspace(-1.0, 1.0, pixels.shape[2])
        seen = match.sum(dim=(1, 2)) > 4
        bearing = (match.sum(dim=1) * columns).sum(dim=1) / match.sum(dim=(1, 2)).clamp_min(1)
        linear = torch.where(seen, 0.8 - 0.5 * bearing.abs(), torch.full_like(bearing, 0.6))
        angular = torch.where(seen, -bearing, torch.full_like(bearing, 0.35))  # image right = turn right
        tensordict.set(("agents", "action"), torch.stack([linear, angular], dim=-1))
        return tensordict


def make_colour_servo() -> ColourServoPolicy:
    """The factory the harness calls once per worker process."""
    return ColourServoPolicy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/example-eval")
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--max-steps", type=int, default=200)
    args = parser.parse_args()

    episodes = make_protocol_episodes(
        "smoke", trials_per_setup=args.trials, trials_per_world=2, max_steps=args.max_steps
    )
    for method in (make_colour_servo, "vrw"):
        result = evaluate(
            method,
            episodes,
            f"{args.out}/{getattr(method, '__name__', method)}",
            videos_per_setup=0,
            maps_per_setup=1,
        )
        for s in result.summaries:
            m = s.metrics
            print(
                f"{s.method:>18} {s.setup}: SR {m.sr:.0%}  SPL {m.spl:.3f}  CR {m.cr:.3f}  "
                f"({m.n_robot_trials} robot-trials)"
            )


if __name__ == "__main__":
    main()
