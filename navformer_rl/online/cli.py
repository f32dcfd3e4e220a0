"""``navformer train-ppo``: the command-line layer over :func:`navformer_rl.online.train.train_ppo`.

Configuration = the packaged ``navformer_rl/config/ppo.yaml`` (or ``--config FILE``) plus hydra-style
``key=value`` overrides (OmegaConf dotlist, no hydra needed)::

    navformer train-ppo method=dsac output_dir=runs/ppo/dsac
    navformer train-ppo method=matdn output_dir=runs/ppo/matdn collector.total_frames=500000
    navformer train-ppo method=matdn output_dir=runs/ppo/matdn resume=true
    navformer train-ppo --compare runs/ppo/dsac runs/ppo/matdn --out runs/ppo/curves.png
"""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  navformer train-ppo method=dsac output_dir=runs/ppo/dsac
  navformer train-ppo method=matdn output_dir=runs/ppo/matdn collector.num_workers=2 env.robot_counts=[4]
  navformer train-ppo method=matdn output_dir=runs/ppo/matdn resume=true
  navformer train-ppo --print-config method=matdn
  navformer train-ppo --compare runs/ppo/dsac runs/ppo/matdn --out runs/ppo/curves.png
  navformer evaluate --method dsac --checkpoint runs/ppo/dsac --protocol table1 --out runs/eval/dsac

methods: dsac (Zhu et al. 2017), matdn (Mezghani et al. 2022); every key: docs/baselines.md
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``train-ppo`` subcommand to the ``navformer`` CLI."""
    parser = subparsers.add_parser(
        "train-ppo",
        help="train the DSAC / MA-TDN baselines online with PPO (paper §VII.A)",
        description="Train DSAC or MA-TDN with PPO (TorchRL ClipPPOLoss + GAE, multi-process collector) in "
        "MultiRobotNavEnv mazes on a shaped reward, with checkpoints, resume, progress.csv and a learning "
        "curve. Configure with key=value overrides of the packaged ppo.yaml.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "overrides",
        nargs="*",
        metavar="KEY=VALUE",
        help="hydra-style overrides of ppo.yaml, e.g. method=matdn collector.total_frames=100000",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file to read instead of the packaged ppo.yaml (keys it leaves out keep their defaults)",
    )
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the resolved configuration as YAML and exit (a valid --config FILE)",
    )
    parser.add_argument(
        "--compare",
        nargs="+",
        metavar="RUN",
        help="plot the learning curves of these run folders together into --out (trains nothing)",
    )
    parser.add_argument("--out", metavar="PNG", help="the plot --compare writes")
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Resolve the configuration, train, print where the results are (or plot runs with ``--compare``)."""
    if args.compare:
        return compare(args.compare, args.out, args.overrides)
    from navformer_rl.online.config import load_ppo_config, validate_ppo_config

    cfg = load_ppo_config(args.overrides, args.config)
    validate_ppo_config(cfg)
    if args.print_config:
        import yaml

        print(yaml.safe_dump(cfg.to_dict(), sort_keys=False), end="")
        return 0
    from navformer_rl.online.train import train_ppo

    print(train_ppo(cfg).summary())
    return 0


def compare(run_dirs: list[str], out: str | None, overrides: list[str]) -> int:
    """``--compare RUN ... --out PNG``: one learning-curve plot of several runs, each labelled with its
    method (and its folder when two runs share a method)."""
    import json
    from pathlib import Path

    from navformer_rl.online.curve import PROGRESS_FILENAME, plot_learning_curves
    from navformer_rl.online.train import CONFIG_FILENAME

    if overrides:
        raise ValueError(f"--compare plots finished runs and takes no overrides; got {' '.join(overrides)}")
    if not out:
        raise ValueError("--compare needs --out PNG, the file to write")
    methods = []
    for run_dir in run_dirs:
        folder = Path(run_dir)
        if not (folder / PROGRESS_FILENAME).is_file() or not (folder / CONFIG_FILENAME).is_file():
            raise ValueError(
                f"--compare {run_dir}: no {PROGRESS_FILENAME} and {CONFIG_FILENAME} there; expected a "
                "`navformer train-ppo` run folder"
            )
        try:
            methods.append(json.loads((folder / CONFIG_FILENAME).read_text())["method"])
        except (ValueError, KeyError, TypeError):
            raise ValueError(
                f"--compare {run_dir}: {CONFIG_FILENAME} is not a train-ppo configuration (no method)"
            ) from None
    runs = {}
    for run_dir, method in zip(run_dirs, methods):
        label = method if methods.count(method) == 1 else f"{method} ({run_dir})"
        runs[label] = Path(run_dir) / PROGRESS_FILENAME
    print(f"wrote {plot_learning_curves(runs, out, 'PPO learning curves')}")
    return 0
