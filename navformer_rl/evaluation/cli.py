"""``navformer evaluate``: run a method on an episode set; ``evaluate make-episodes`` / ``report`` / ``seeds``.

Examples::

    navformer evaluate --method fca --protocol table1 --out runs/eval/fca --workers 2
    navformer evaluate --method navformer --checkpoint runs/train --episodes table1.json --out runs/eval/nf
    navformer evaluate make-episodes --protocol table1 --out table1.json
    navformer evaluate report runs/eval/vrw runs/eval/fca runs/eval/nf --out runs/eval/README.md
    navformer evaluate seeds --group navformer runs/eval/nf_s0 runs/eval/nf_s1 --group dt runs/eval/dt_s0
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from navformer_rl import cli_args
from navformer_rl.constants import MAX_EPISODE_STEPS


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``evaluate`` subcommand (with ``make-episodes`` and ``report``) to the ``navformer`` CLI.

    Every parser sets ``run`` (``args.run(args) -> int``), the convention of ``navformer_rl.cli``.
    """
    from navformer_rl.evaluation.episodes import PROTOCOLS
    from navformer_rl.evaluation.harness import METHODS

    parser = subparsers.add_parser(
        "evaluate",
        help="measure SR / SPL / CR of a method on fixed episodes (paper §VII)",
        description="Run a method on every episode of an episode set (a file, or a protocol generated on the "
        "fly) and write per-robot-trial JSONL, a Table I-layout CSV/markdown with 95 % CIs, bar plots, "
        "top-down maps and videos into --out.",
    )
    parser.add_argument("--method", help=f"one of: {', '.join(METHODS)}")
    parser.add_argument(
        "--checkpoint",
        help="navformer, dt: a run dir, its checkpoints/ or checkpoints/latest, a checkpoint folder "
        "(checkpoints/iter_XXXXXX) or its model.safetensors",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--episodes", type=Path, help="episode-set JSON file (from `evaluate make-episodes`)")
    source.add_argument("--protocol", help=f"generate the episodes of a protocol: {', '.join(PROTOCOLS)}")
    _add_generation_options(parser)
    parser.add_argument("--out", type=cli_args.output_folder, help="output folder")
    parser.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    parser.add_argument(
        "--videos", type=int, default=1, help="episodes per setup recorded as mp4 (default 1)"
    )
    parser.add_argument(
        "--maps", type=int, default=2, help="episodes per setup drawn as top-down maps (default 2)"
    )
    parser.add_argument(
        "--label",
        help="method name in tables (default: --method), e.g. navformer-no_thsc (a label naming a training "
        "ablation must be the checkpoint's)",
    )
    parser.add_argument(
        "--seed", type=cli_args.seed, default=0, help="seed of stochastic policies (default 0)"
    )
    _add_cluster_option(parser, "trial")
    parser.add_argument(
        "--device",
        default="cpu",
        help="where navformer / dt run their model: cpu (default), cuda, cuda:N or auto; the simulation "
        "always runs on the CPU",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--fresh", action="store_true", help="recompute every episode (default: reuse finished ones in --out)"
    )
    parser.set_defaults(run=_run_evaluate)

    commands = parser.add_subparsers(dest="evaluate_command", metavar="{make-episodes,report,seeds}")
    make = commands.add_parser(
        "make-episodes",
        help="write a fixed, versioned episode-set file",
        description="Generate the episodes of a protocol (seeded, deterministic) and save them as JSON.",
    )
    make.add_argument("--protocol", dest="make_protocol", required=True, help=", ".join(PROTOCOLS))
    make.add_argument(
        "--out", dest="make_out", type=Path, required=True, help="episode-set JSON file to write"
    )
    make.add_argument(
        "--workers", dest="make_workers", type=int, default=1,
        help="parallel processes (default 1); the episodes do not depend on it",
    )  # fmt: skip
    _add_generation_options(make)
    make.set_defaults(run=_run_make_episodes)

    report = commands.add_parser(
        "report",
        help="markdown report over several evaluation folders, beside the paper's numbers",
        description="Combine evaluation folders (one per method) into one markdown report with tables, "
        "plots, links to maps/videos and the paper's Table I.",
    )
    report.add_argument(
        "folders", nargs="+", type=Path, help="evaluation folders (from `navformer evaluate`)"
    )
    report.add_argument("--out", dest="report_out", type=Path, required=True, help="report .md file to write")
    report.add_argument("--title", default="NavFormer evaluation")
    _add_cluster_option(report, None)
    report.set_defaults(run=_run_report)

    seeds = commands.add_parser(
        "seeds",
        help="SR / SPL / CR over training seeds: per seed, mean ± std, pooled",
        description="Summarise evaluation folders of several trained seeds per configuration: each seed's "
        "SR, the mean ± standard deviation over seeds of SR / SPL / CR, and the pooled SR / CR with "
        "trial-clustered intervals. Every folder must have run the same episode set.",
    )
    seeds.add_argument(
        "--group",
        dest="seed_groups",
        nargs="+",
        action="append",
        required=True,
        metavar=("NAME", "FOLDER"),
        help="a configuration's name, then its evaluation folders (one per trained seed); repeat per group",
    )
    seeds.add_argument(
        "--out",
        dest="seeds_out",
        type=Path,
        metavar="FILE",
        help="also write the markdown table to this file",
    )
    seeds.add_argument(
        "--json", dest="seeds_json", action="store_true", help="print JSON instead of markdown"
    )
    _add_cluster_option(seeds, "trial")
    seeds.set_defaults(run=_run_seeds)
    return parser


def _add_cluster_option(parser: argparse.ArgumentParser, default: str | None) -> None:
    from navformer_rl.evaluation.measures import CLUSTER_LEVELS

    default_text = "the folders' own choice, trial when they differ" if default is None else default
    parser.add_argument(
        "--cluster-by",
        choices=CLUSTER_LEVELS,
        default=default,
        help="what the confidence intervals resample: trial (intervals for these mazes) or world (also the "
        f"variation between mazes; needs 6 mazes per setup); default: {default_text}",
    )


def _add_generation_options(parser: argparse.ArgumentParser) -> None:
    """Options that shape generated episodes (default None = the paper's value, see ``_generation``)."""
    from navformer_rl.evaluation.episodes import PAPER_TRIALS_PER_SETUP, PAPER_TRIALS_PER_WORLD

    parser.add_argument(
        "--trials-per-setup",
        type=int,
        help=f"with --protocol: trials per setup (default and paper: {PAPER_TRIALS_PER_SETUP})",
    )
    parser.add_argument(
        "--trials-per-world",
        type=int,
        help=f"with --protocol: trials per world (default and paper: {PAPER_TRIALS_PER_WORLD})",
    )
    parser.add_argument(
        "--episode-seed", type=cli_args.seed, help="with --protocol: generation seed (default 0)"
    )
    parser.add_argument(
        "--max-steps",
        type=int,
        help=f"with --protocol: steps per trial (default and paper: {MAX_EPISODE_STEPS})",
    )
    parser.add_argument(
        "--setups",
        type=_setup_names,
        help="with --protocol: only these of its setups, comma-separated (e.g. 7.5m-2r,12.5m-4r; default: all)",
    )


def _setup_names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


_GENERATION_OPTIONS = ("trials_per_setup", "trials_per_world", "episode_seed", "max_steps")
"""Positional arguments of ``make_protocol_episodes`` after the protocol (``--setups`` is a keyword)."""


def _generation(args: argparse.Namespace) -> tuple[int, ...]:
    """(trials per setup, trials per world, episode seed, max steps) with the defaults filled in."""
    from navformer_rl.evaluation.episodes import PAPER_TRIALS_PER_SETUP, PAPER_TRIALS_PER_WORLD

    defaults = (PAPER_TRIALS_PER_SETUP, PAPER_TRIALS_PER_WORLD, 0, MAX_EPISODE_STEPS)
    return tuple(
        default if getattr(args, name) is None else getattr(args, name)
        for name, default in zip(_GENERATION_OPTIONS, defaults)
    )


def _run_evaluate(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.episodes import load_episode_set, make_protocol_episodes
    from navformer_rl.evaluation.harness import METHODS, PolicySpec, evaluate

    if args.method is None:
        raise ValueError(f"--method is required: one of {', '.join(METHODS)}")
    if args.out is None:
        raise ValueError("--out DIR is required")
    if args.episodes is None and args.protocol is None:
        raise ValueError("give the episodes: --episodes FILE or --protocol {table1,table3,table4,smoke}")
    # Refuse a bad method / checkpoint / label before spending time on episode generation.
    PolicySpec(args.method, args.checkpoint, args.seed, device=args.device).validate(args.label)
    if args.episodes is not None:
        given = [name for name in (*_GENERATION_OPTIONS, "setups") if getattr(args, name) is not None]
        if given:  # the file fixes them: silently ignoring them would run other episodes than asked for
            flags = ", ".join("--" + name.replace("_", "-") for name in given)
            raise ValueError(
                f"{flags}: only with --protocol; the episode file {args.episodes} fixes its trials, seeds and "
                "steps per trial (make another with `navformer evaluate make-episodes`)"
            )
        episode_set = load_episode_set(args.episodes)
    else:
        episode_set = make_protocol_episodes(
            args.protocol, *_generation(args), workers=args.workers, setups=args.setups
        )
    result = evaluate(
        args.method,
        episode_set,
        args.out,
        checkpoint=args.checkpoint,
        workers=args.workers,
        label=args.label,
        seed=args.seed,
        maps_per_setup=args.maps,
        videos_per_setup=args.videos,
        cluster=args.cluster_by,
        device=args.device,
        progress=not args.no_progress,
        resume=not args.fresh,
    )
    print((result.out_dir / "summary.md").read_text(), end="")
    print(f"results in {result.out_dir}")
    return 0


def _output_file(path: Path, option: str) -> Path:
    """``path`` if it can be written as a file (ValueError when it is a folder)."""
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder; expected the path of a file to write")
    return path


def _run_make_episodes(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.episodes import load_episode_set, make_protocol_episodes, save_episode_set

    out = _output_file(args.make_out, "--out")
    episode_set = make_protocol_episodes(
        args.make_protocol, *_generation(args), workers=args.make_workers, setups=args.setups
    )
    if out.exists():  # the same episodes again is fine; anything else would be lost
        try:
            same = load_episode_set(out).content_hash() == episode_set.content_hash()
        except (ValueError, OSError):
            same = False
        if not same:
            raise FileExistsError(
                f"--out {out} exists and holds something else; choose another path or delete it"
            )
    path = save_episode_set(episode_set, out)
    print(f"wrote {len(episode_set)} episodes ({', '.join(episode_set.setups)}) to {path}")
    return 0


def _run_seeds(args: argparse.Namespace) -> int:
    from navformer_rl.durable import atomic_write_text
    from navformer_rl.evaluation.seeds import seed_table_markdown, summarize_seed_groups

    groups: dict[str, list[Path]] = {}
    for name, *folders in args.seed_groups:
        if not folders:
            raise ValueError(f"--group {name}: give the group's evaluation folders after its name")
        if name in groups:
            raise ValueError(f"--group {name} is given twice; give each group's folders once")
        groups[name] = [Path(folder) for folder in folders]
    out = _output_file(args.seeds_out, "--out") if args.seeds_out is not None else None
    summaries = summarize_seed_groups(groups, cluster=args.cluster_by)
    table = seed_table_markdown(summaries)
    if out is not None:
        atomic_write_text(out, table)
    if args.seeds_json:
        print(json.dumps([s.to_dict() for s in summaries], indent=2))
    else:
        print(table, end="")
    return 0


def _run_report(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.report import write_report

    path = write_report(
        args.folders, _output_file(args.report_out, "--out"), title=args.title, cluster=args.cluster_by
    )
    print(f"wrote {path}")
    return 0
