"""``navformer train``: the command-line layer over :func:`navformer_rl.training.train`.

Configuration = the packaged ``navformer_rl/config/train.yaml`` (or ``--config FILE``) plus hydra-style
``key=value`` overrides, parsed with OmegaConf's dotlist (no hydra needed)::

    navformer train data.exploration_path=/data/e data.collision_path=/data/ca data.ssl_path=/data/ssl
    navformer train ... ablation=no_ssl optim.iterations=2000 output_dir=runs/no_ssl
    navformer train ... output_dir=runs/navformer resume=true      # continue from the latest checkpoint
    navformer train ... init_from=pretrained:navformer output_dir=runs/ft   # fine-tune trained weights
    torchrun --nproc-per-node 2 -m navformer_rl train ...          # data-parallel (global batch sizes)
"""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  navformer train data.exploration_path=/data/e data.collision_path=/data/ca data.ssl_path=/data/ssl
  navformer train ... ablation=no_thsc output_dir=runs/no_thsc
  navformer train ... model.autocast_dtype=bfloat16 model.encoder_micro_batch=512   # CPU levers
  navformer train ... output_dir=runs/navformer resume=true
  navformer train ... init_from=runs/navformer output_dir=runs/finetuned    # fine-tune: fresh optimisers
  torchrun --nproc-per-node 2 -m navformer_rl train ...   # data-parallel; the batch sizes are global
  navformer train --print-config ablation=dt        # resolved_model: the model the run builds

ablations (paper Table IV + DT baseline): {ablations}
every key: docs/training.md
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``train`` subcommand to the ``navformer`` CLI."""
    from navformer_rl.tasks import ABLATIONS

    parser = subparsers.add_parser(
        "train",
        help="train NavFormer on D_e / D_ca / D_ssl (paper §VI)",
        description="Cross-task training of NavFormer: L = L_BYOL + L_DT (paper eq. 11), with checkpoints "
        "and resume. Configure with key=value overrides of the packaged train.yaml.",
        epilog=EPILOG.format(ablations=", ".join(ABLATIONS)),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "overrides",
        nargs="*",
        metavar="KEY=VALUE",
        help="hydra-style overrides of train.yaml, e.g. optim.lr=1e-4 data.ssl_path=/data/ssl",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file to read instead of the packaged train.yaml (keys it leaves out keep their defaults)",
    )
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the resolved configuration as YAML and exit; its resolved_model section is the model "
        "the run builds (after the ablation and model.* overrides). The output is a valid --config FILE",
    )
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Resolve the configuration, train, print where the results are."""
    from navformer_rl.training.config import validate_config
    from navformer_rl.training.config_io import load_train_config, printable_config

    cfg = load_train_config(args.overrides, args.config)
    if args.print_config:
        from omegaconf import OmegaConf

        validate_config(cfg, require_data=False)  # the datasets may not exist yet
        print(OmegaConf.to_yaml(printable_config(cfg)), end="")
        return 0
    validate_config(cfg)  # a bad setting is answered before torch is imported
    from navformer_rl.training.distributed import is_main_process
    from navformer_rl.training.run import train

    result = train(cfg)
    if is_main_process():  # under torchrun every process trains; rank 0 reports
        print(result.summary())
    return 0
