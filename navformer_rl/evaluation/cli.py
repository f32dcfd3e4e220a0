"""``navformer evaluate``: run a method on an episode set; ``evaluate make-episodes`` / ``report`` /
``seeds``.

Examples::

    navformer evaluate --method fca --protocol table1 --out runs/eval/fca --workers 2
    navformer evaluate --method fca --episodes table1.json --out runs/eval/fca --backend ray --workers 8
    navformer evaluate --method navformer --checkpoint runs/train --episodes table1.json --out runs/eval/nf
    navformer evaluate --method dt --checkpoint pretrained:dt --protocol table1 --out runs/eval/dt_shipped
    navformer evaluate make-episodes --protocol table1 --out table1.json
    navformer evaluate report runs/eval/vrw runs/eval/fca runs/eval/nf --out runs/eval/README.md
    navformer evaluate seeds --group navformer runs/eval/nf_s0 runs/eval/nf_s1 --group dt runs/eval/dt_s0
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from navformer_rl.constants import MAX_EPISODE_STEPS
from navformer_rl.utils import cli_args
from navformer_rl.utils.backends import add_backend_options, backend_problem


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``evaluate`` subcommand (with ``make-episodes`` and ``report``) to the ``navformer`` CLI.

    Every parser sets ``run`` (``args.run(args) -> int``), the convention of ``navformer_rl.cli``.
    """
    from navformer_rl.evaluation.episodes import PROTOCOLS
    from navformer_rl.evaluation.policy_spec import METHODS

    parser = subparsers.add_parser(
        "evaluate",
        help="measure SR / SPL / CR of a method on fixed episodes (paper §VII)",
        description="Run a method on every episode of an episode set (a file, or a protocol generated on the "
        "fly) and write per-robot-trial JSONL, a Table I-layout CSV/markdown with 95 % CIs, bar plots, "
        "top-down maps and videos into --out.",
    )
    parser.add_argument("--method", choices=METHODS, help=f"one of: {', '.join(METHODS)}")
    parser.add_argument(
        "--checkpoint",
        help="navformer, dt: a run dir, its checkpoints/ or checkpoints/latest, a checkpoint folder "
        "(checkpoints/iter_XXXXXX) or its model.safetensors; or shipped weights: pretrained:navformer, "
        "pretrained:dt (`navformer pretrained list`); dsac, matdn: a `navformer train-ppo` run dir or one "
        "of its checkpoint folders",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--episodes", type=Path, help="episode-set JSON file (from `evaluate make-episodes`)")
    source.add_argument(
        "--protocol", choices=PROTOCOLS, help=f"generate the episodes of a protocol: {', '.join(PROTOCOLS)}"
    )
    _add_generation_options(parser)
    parser.add_argument("--out", type=cli_args.output_folder, help="output folder")
    parser.add_argument(
        "--workers",
        type=cli_args.int_at_least(1),
        default=1,
        help="parallel processes, or Ray tasks at once with --backend ray (default 1)",
    )
    add_backend_options(parser, "episodes")
    parser.add_argument(
        "--videos",
        type=cli_args.int_at_least(0),
        default=1,
        help="episodes per setup recorded as mp4 (default 1)",
    )
    parser.add_argument(
        "--maps",
        type=cli_args.int_at_least(0),
        default=2,
        help="episodes per setup drawn as top-down maps (default 2)",
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
    parser.add_argument(
        "--context-steps",
        type=cli_args.int_at_least(1),
        default=None,
        help="navformer, dt: the timesteps the policy attends to, from 1 to the model's window (default: "
        "the window the checkpoint was trained on, data.context_steps, else the whole context: 256 steps for "
        "navformer, 341 for dt; a "
        "shorter one is an inference option, not the paper's)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--fresh", action="store_true", help="recompute every episode (default: reuse finished ones in --out)"
    )
    parser.set_defaults(run=_run_evaluate)

    commands = parser.add_subparsers(
        dest="evaluate_command",
        metavar="{make-episodes,report,seeds,compare,ablations,unseen,diagnose,probe,strip}",
    )
    make = commands.add_parser(
        "make-episodes",
        help="write a fixed, versioned episode-set file",
        description="Generate the episodes of a protocol (seeded, deterministic) and save them as JSON.",
    )
    make.add_argument(
        "--protocol", dest="make_protocol", choices=PROTOCOLS, required=True, help=", ".join(PROTOCOLS)
    )
    make.add_argument(
        "--out", dest="make_out", type=Path, required=True, help="episode-set JSON file to write"
    )
    make.add_argument(
        "--workers", dest="make_workers", type=cli_args.int_at_least(1), default=1,
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
    _add_named_folders(
        seeds,
        "--group",
        "seed_groups",
        "a configuration's name, then its evaluation folders (one per trained seed); repeat per group",
        required=True,
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
    seeds.add_argument(
        "--plot",
        dest="seeds_plot",
        type=Path,
        metavar="PNG",
        help="also draw SR per group (mean ± std, each seed a dot; a group of one run: its 95 %% interval); "
        "groups named SERIES@X (e.g. navformer@3496) become one line per SERIES over X",
    )
    seeds.add_argument("--x-label", dest="seeds_x_label", default="x", help="--plot's x-axis label")
    seeds.add_argument(
        "--x-scale",
        dest="seeds_x_scale",
        choices=("auto", "linear", "log"),
        default="auto",
        help=(
            "--plot's x axis: auto (logarithmic when the largest X is at least 5x the smallest), linear, log"
        ),
    )
    _add_cluster_option(seeds, "trial")
    seeds.set_defaults(run=_run_seeds)

    compare = commands.add_parser(
        "compare",
        help="paired difference A - B of SR / SPL / CR on the same episodes, with intervals",
        description="Compare two evaluation folders of one episode set robot-trial by robot-trial: per setup "
        "and pooled, the mean difference A - B of success, SPL and CR with a cluster-bootstrap interval "
        "(docs/evaluation.md, 'Paired comparisons'). Two models trained with several seeds: --group NAME "
        "FOLDER... twice, each robot-trial averaged over a model's seeds and the interval resampling the "
        "seeds too.",
    )
    compare.add_argument(
        "compare_a", type=Path, nargs="?", metavar="A", help="evaluation folder of the first method"
    )
    compare.add_argument(
        "compare_b", type=Path, nargs="?", metavar="B", help="evaluation folder of the second method"
    )
    _add_named_folders(
        compare,
        "--group",
        "compare_groups",
        "instead of A B: a model's name, then its evaluation folders (one per training seed); give two",
        required=False,
    )
    compare.add_argument(
        "--episodes",
        dest="compare_episodes",
        type=Path,
        nargs="+",
        metavar="FILE",
        help="the episode files of folders that ran different sets: they pair when the sets hold the same "
        "robots and differ only in their distractors (e.g. table2 against --distractors 0)",
    )
    compare.add_argument(
        "--out",
        dest="compare_out",
        type=Path,
        metavar="FILE",
        help="also write the markdown table to this file",
    )
    _add_cluster_option(compare, "trial")
    compare.set_defaults(run=_run_compare)

    ablations = commands.add_parser(
        "ablations",
        help="Table IV: each ablation - the full model on one setup, with a verdict on the paper's sign",
        description="Each ablation against the full model on the same robot-trials of one setup (Table IV's "
        "12.5m-4r by default, 'all' pools every setup): its SR / SPL / CR, the paired SR difference pooled "
        "over each side's seeds, the full model's seed-to-seed SR spread and a verdict on the paper's claim "
        "that removing the part lowers SR: holds / does not hold / cannot tell (docs/evaluation.md, "
        "'Ablation verdicts').",
    )
    ablations.add_argument(
        "--full",
        dest="ablations_full",
        nargs="+",
        required=True,
        type=Path,
        metavar="FOLDER",
        help="the full model's evaluation folders, one per training seed",
    )
    _add_named_folders(
        ablations,
        "--ablation",
        "ablations_groups",
        "an ablation's name, then its evaluation folders (one per training seed); repeat per ablation",
        required=True,
    )
    ablations.add_argument(
        "--setup", dest="ablations_setup", default="12.5m-4r", help="the setup judged, or 'all' (12.5m-4r)"
    )
    ablations.add_argument(
        "--out", dest="ablations_out", type=Path, metavar="FILE", help="also write the markdown table here"
    )
    _add_cluster_option(ablations, "trial")
    ablations.set_defaults(run=_run_ablations)

    unseen = commands.add_parser(
        "unseen",
        help="Table III's drop: each robot with unseen obstacle robots - the same robot with seen ones",
        description="For table3 evaluation folders (one per method): every robot measured among unseen "
        "obstacle robots against the same robot, maze, start and target among seen ones, with a trial-"
        "bootstrap interval (docs/evaluation.md, 'Paired comparisons').",
    )
    unseen.add_argument(
        "unseen_folders", type=Path, nargs="+", metavar="DIR", help="table3 evaluation folders"
    )
    unseen.add_argument(
        "--out", dest="unseen_out", type=Path, metavar="FILE", help="also write the table here"
    )
    unseen.set_defaults(run=_run_unseen)
    _register_diagnose(commands, METHODS)
    return parser


def _register_diagnose(commands: argparse._SubParsersAction, methods: tuple[str, ...]) -> None:
    """``evaluate diagnose``: per-step records and failure measures (``navformer_rl.evaluation.diagnose``)."""
    diagnose = commands.add_parser(
        "diagnose",
        help="where and how a method fails: walls, circling, target in view, progress, turns",
        description="Run a method on an episode set recording every robot's every step, and write "
        "diagnosis.json / diagnosis.md (docs/evaluation.md, 'Diagnosing failures').",
    )
    diagnose.add_argument("--method", dest="diag_method", choices=methods, required=True)
    diagnose.add_argument("--checkpoint", dest="diag_checkpoint", help="navformer, dt: as for `evaluate`")
    diagnose.add_argument(
        "--episodes", dest="diag_episodes", type=Path, required=True, help="episode-set file"
    )
    diagnose.add_argument("--out", dest="diag_out", type=cli_args.output_folder, required=True)
    diagnose.add_argument("--workers", dest="diag_workers", type=cli_args.int_at_least(1), default=1)
    diagnose.add_argument("--label", dest="diag_label", help="name in the tables (default: --method)")
    diagnose.add_argument("--seed", dest="diag_seed", type=cli_args.seed, default=0, help="as for `evaluate`")
    diagnose.add_argument("--device", dest="diag_device", default="cpu", help="as for `evaluate`")
    diagnose.add_argument(
        "--context-steps", dest="diag_context_steps", type=cli_args.int_at_least(1), default=None,
        help="as for `evaluate`",
    )  # fmt: skip
    diagnose.add_argument(
        "--expert-data", dest="diag_expert_data", nargs=2, type=Path, metavar=("DIR_E", "DIR_CA"),
        help="D_e and D_ca folders whose actions are set beside the policy's commands",
    )  # fmt: skip
    diagnose.add_argument(
        "--held-out", dest="diag_held_out", nargs=2, type=Path, metavar=("DIR_E", "DIR_CA"),
        help="held-out D_e and D_ca folders for the teacher-forced turns (navformer, dt)",
    )  # fmt: skip
    diagnose.add_argument(
        "--compare", dest="diag_compare", nargs="+", type=Path, default=[], metavar="DIR",
        help="other diagnosis folders of the same episodes (e.g. fca, vrw), shown beside this one",
    )  # fmt: skip
    diagnose.add_argument("--no-progress", dest="diag_no_progress", action="store_true")
    diagnose.add_argument(
        "--fresh", dest="diag_fresh", action="store_true", help="recompute every episode's trace"
    )
    diagnose.set_defaults(run=_run_diagnose)

    pair = commands.add_parser(
        "diagnose-pair",
        help="two diagnoses of the same episodes paired: success, sighting and stuck shares, A - B",
        description="For two `evaluate diagnose` folders of the same episode set: the share of robot-trials "
        "that succeed, see their target within 3 m and end stuck, and A - B paired robot-trial by "
        "robot-trial with a trial-bootstrap interval (docs/evaluation.md, 'Diagnosing failures').",
    )
    pair.add_argument("pair_a", type=Path, metavar="A", help="diagnosis folder")
    pair.add_argument("pair_b", type=Path, metavar="B", help="diagnosis folder of the same episodes")
    pair.add_argument(
        "--setups", dest="pair_setups", type=lambda text: tuple(text.split(",")), default=None,
        help="only these setups, comma-separated (default: all)",
    )  # fmt: skip
    pair.add_argument("--out", dest="pair_out", type=Path, metavar="FILE", help="also write the table here")
    pair.set_defaults(run=_run_diagnose_pair)

    probe = commands.add_parser(
        "probe",
        help="what checkpoints' encoders keep of a frame: linear probes on held-out D_e (or D_ca)",
        description="Fit linear probes from each checkpoint's frame embeddings (every encoder alone and all "
        "together) to the expert's action, whether the target is in view and its bearing, on half of the "
        "held-out trajectories, scored on the other half; write probe.json / probe.md (docs/evaluation.md, "
        "'Probing the encoders').",
    )
    probe.add_argument(
        "--model", dest="probe_models", nargs=2, action="append", required=True,
        metavar=("LABEL", "CHECKPOINT"),
        help="a name for the table and a checkpoint (a run folder, a checkpoint folder, pretrained:NAME); "
        "repeat for each model",
    )  # fmt: skip
    probe.add_argument(
        "--held-out", dest="probe_held_out", type=Path, required=True, metavar="DIR",
        help="a D_e folder (or D_ca with --kind ca) from worlds the checkpoints did not train on",
    )  # fmt: skip
    probe.add_argument(
        "--kind", dest="probe_kind", choices=("e", "ca"), default="e",
        help="the held-out dataset's kind (default e)",
    )  # fmt: skip
    probe.add_argument("--out", dest="probe_out", type=cli_args.output_folder, required=True)
    probe.add_argument(
        "--max-trajectories", dest="probe_max_trajectories", type=cli_args.int_at_least(2), default=None,
        help="the first N trajectories of the seeded permutation (default: all)",
    )  # fmt: skip
    probe.add_argument("--seed", dest="probe_seed", type=cli_args.seed, default=0, help="the windows' seed")
    probe.add_argument("--device", dest="probe_device", default="cpu")
    probe.set_defaults(run=_run_probe)

    strip = commands.add_parser(
        "strip",
        help="evenly spaced frames of an evaluation video side by side in one PNG",
        description=(
            "Write a frame strip of an evaluation video (videos/*.mp4): --frames evenly spaced frames, "
            "first and last included, side by side and scaled to --width pixels, each labelled with its step "
            "and its time in the trial (frame i is step i, 0.2 s per step; not the video's playback time)."
        ),
    )
    strip.add_argument("strip_video", type=Path, metavar="VIDEO", help="an mp4 from an evaluation's videos/")
    strip.add_argument("--out", dest="strip_out", type=Path, required=True, help="the .png to write")
    strip.add_argument("--frames", dest="strip_frames", type=cli_args.int_at_least(1), default=5)
    strip.add_argument("--width", dest="strip_width", type=cli_args.int_at_least(16), default=1600)
    strip.set_defaults(run=_run_strip)


def _add_named_folders(
    parser: argparse.ArgumentParser, option: str, dest: str, help: str, required: bool
) -> None:
    """A repeatable ``option NAME FOLDER...`` (a model's or an ablation's name, then its folders)."""
    parser.add_argument(
        option,
        dest=dest,
        nargs="+",
        action="append",
        required=required,
        metavar=("NAME", "FOLDER"),
        help=help,
    )


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
        type=cli_args.int_at_least(1),
        help=f"with --protocol: trials per setup (default and paper: {PAPER_TRIALS_PER_SETUP}; table2: 30)",
    )
    parser.add_argument(
        "--trials-per-world",
        type=cli_args.int_at_least(1),
        help=f"with --protocol: trials per world (default and paper: {PAPER_TRIALS_PER_WORLD})",
    )
    parser.add_argument(
        "--episode-seed", type=cli_args.seed, help="with --protocol: generation seed (default 0)"
    )
    parser.add_argument(
        "--max-steps",
        type=cli_args.int_at_least(1),
        help=f"with --protocol: steps per trial (default and paper: {MAX_EPISODE_STEPS})",
    )
    parser.add_argument(
        "--setups",
        type=_setup_names,
        help=(
            "with --protocol: only these of its setups, comma-separated (e.g. 7.5m-2r,12.5m-4r; default: all)"
        ),
    )
    parser.add_argument(
        "--distractors",
        type=cli_args.int_at_least(0),
        help="with --protocol: targets no robot seeks in every episode, beside the robots' own (default: the "
        "protocol's, table2: 5 for Fig. 4's eight targets, the others 0); the robots' starts and targets do "
        "not depend on it",
    )


def _setup_names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def _check_setups(protocol: str, setups: list[str] | None) -> None:
    """ValueError naming ``--setups`` when it lists a setup that ``protocol`` lacks (or none at all)."""
    from navformer_rl.evaluation.episodes import protocol_setups

    if setups is None:
        return
    names = [setup.name for setup in protocol_setups(protocol)]
    unknown = [name for name in setups if name not in names]
    if unknown or not setups:
        raise ValueError(
            f"--setups {','.join(setups)!r}: expected setups of --protocol {protocol}, comma-separated: "
            f"{','.join(names)}"
        )


_GENERATION_OPTIONS = ("trials_per_setup", "trials_per_world", "episode_seed", "max_steps")
"""Positional arguments of ``make_protocol_episodes`` after the protocol (``--setups`` and ``--distractors``
are keywords)."""


def _generation(args: argparse.Namespace) -> tuple[int | None, ...]:
    """(trials per setup, trials per world, episode seed, max steps) with the defaults filled in (None: the
    protocol's trials, see ``episodes.protocol_trials``)."""
    defaults = (None, None, 0, MAX_EPISODE_STEPS)
    return tuple(
        default if getattr(args, name) is None else getattr(args, name)
        for name, default in zip(_GENERATION_OPTIONS, defaults)
    )


def _run_evaluate(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.episodes import load_episode_set, make_protocol_episodes
    from navformer_rl.evaluation.harness import METHODS, EvaluateConfig, PolicySpec, evaluate

    if args.method is None:
        raise ValueError(f"--method is required: one of {', '.join(METHODS)}")
    if args.out is None:
        raise ValueError("--out DIR is required")
    if args.episodes is None and args.protocol is None:
        raise ValueError(
            "give the episodes: --episodes FILE or --protocol {table1,table2,table3,table4,smoke}"
        )
    # Refuse a bad method / checkpoint / label / backend before spending time on episode generation.
    PolicySpec(
        args.method, args.checkpoint, args.seed, device=args.device, context_steps=args.context_steps
    ).validate(args.label)
    problem = backend_problem(args)
    if problem is not None:
        raise ValueError(problem)
    if args.episodes is not None:
        options = (*_GENERATION_OPTIONS, "setups", "distractors")
        given = [name for name in options if getattr(args, name) is not None]
        if given:  # the file fixes them: silently ignoring them would run other episodes than asked for
            flags = ", ".join("--" + name.replace("_", "-") for name in given)
            raise ValueError(
                f"{flags}: only with --protocol; the episode file {args.episodes} fixes its trials, seeds "
                "and steps per trial (make another with `navformer evaluate make-episodes`)"
            )
        episode_set = load_episode_set(args.episodes)
    else:
        _check_setups(args.protocol, args.setups)
        # generated here: with Ray, --workers may count a cluster's CPUs
        workers = args.workers if args.backend == "local" else min(args.workers, len(os.sched_getaffinity(0)))
        episode_set = make_protocol_episodes(
            args.protocol,
            *_generation(args),
            workers=workers,
            setups=args.setups,
            distractors=args.distractors,
        )
    config = EvaluateConfig(
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
        backend=args.backend,
        ray_address=args.ray_address,
        context_steps=args.context_steps,
    )
    result = evaluate(args.method, episode_set, args.out, config)
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
    _check_setups(args.make_protocol, args.setups)
    episode_set = make_protocol_episodes(
        args.make_protocol,
        *_generation(args),
        workers=args.make_workers,
        setups=args.setups,
        distractors=args.distractors,
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


def _run_unseen(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.paired import paired_markdown, unseen_obstacle_differences
    from navformer_rl.utils.durable import atomic_write_text

    out = _output_file(args.unseen_out, "--out") if args.unseen_out is not None else None
    rows = [unseen_obstacle_differences(folder)[1] for folder in args.unseen_folders]
    table = paired_markdown(("unseen", "seen"), rows, row_header="Method")
    if out is not None:
        atomic_write_text(out, table)
    print(table, end="")
    return 0


def _run_compare(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.episodes import load_episode_set
    from navformer_rl.evaluation.paired import paired_markdown, pooled_paired_differences
    from navformer_rl.utils.durable import atomic_write_text

    out = _output_file(args.compare_out, "--out") if args.compare_out is not None else None
    episode_sets = [load_episode_set(path) for path in args.compare_episodes or []]
    groups = args.compare_groups or []
    positional = [folder for folder in (args.compare_a, args.compare_b) if folder is not None]
    if groups:
        if positional:
            raise ValueError("give either two folders A B or two --group NAME FOLDER..., not both")
        if len(groups) != 2 or any(len(group) < 2 for group in groups):
            raise ValueError(
                f"--group given {len(groups)} time(s) ({[g[0] for g in groups]}); give it twice, each a name "
                "then at least one evaluation folder"
            )
        (name_a, *folders_a), (name_b, *folders_b) = groups
        labels, rows = pooled_paired_differences(
            [Path(f) for f in folders_a],
            [Path(f) for f in folders_b],
            (name_a, name_b),
            cluster=args.cluster_by,
            episode_sets=episode_sets,
        )
    elif len(positional) == 2:
        labels, rows = pooled_paired_differences(
            [args.compare_a], [args.compare_b], cluster=args.cluster_by, episode_sets=episode_sets
        )
    else:
        raise ValueError(
            "compare needs two evaluation folders A B, or two --group NAME FOLDER... (one folder per seed)"
        )
    table = paired_markdown(labels, rows, cluster=args.cluster_by)
    if out is not None:
        atomic_write_text(out, table)
    print(table, end="")
    return 0


def _run_ablations(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.ablations import ablation_verdicts, ablations_markdown
    from navformer_rl.utils.durable import atomic_write_text

    out = _output_file(args.ablations_out, "--out") if args.ablations_out is not None else None
    groups = []
    for name, *folders in args.ablations_groups:
        if not folders:
            raise ValueError(f"--ablation {name}: give the ablation's evaluation folders after its name")
        groups.append((name, [Path(folder) for folder in folders]))
    rows = ablation_verdicts(args.ablations_full, groups, setup=args.ablations_setup, cluster=args.cluster_by)
    table = ablations_markdown(rows)
    if out is not None:
        atomic_write_text(out, table)
    print(table, end="")
    return 0


def _run_seeds(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.seeds import seed_table_markdown, summarize_seed_groups
    from navformer_rl.utils.durable import atomic_write_text

    groups: dict[str, list[Path]] = {}
    for name, *folders in args.seed_groups:
        if not folders:
            raise ValueError(f"--group {name}: give the group's evaluation folders after its name")
        if name in groups:
            raise ValueError(f"--group {name} is given twice; give each group's folders once")
        groups[name] = [Path(folder) for folder in folders]
    out = _output_file(args.seeds_out, "--out") if args.seeds_out is not None else None
    plot = _output_file(args.seeds_plot, "--plot") if args.seeds_plot is not None else None
    summaries = summarize_seed_groups(groups, cluster=args.cluster_by)
    table = seed_table_markdown(summaries)
    if out is not None:
        atomic_write_text(out, table)
    if plot is not None:
        from navformer_rl.evaluation.plots import plot_seed_groups

        plot_seed_groups(summaries, plot, x_label=args.seeds_x_label, x_scale=args.seeds_x_scale)
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


def _run_strip(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.strip import frame_strip

    print(frame_strip(args.strip_video, args.strip_out, frames=args.strip_frames, width=args.strip_width))
    return 0


def _run_diagnose(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.diagnose import SUMMARY_MD, diagnose

    def kinds(folders):
        return None if folders is None else dict(zip(("e", "ca"), folders))

    diagnose(
        args.diag_method,
        args.diag_episodes,
        args.diag_out,
        checkpoint=args.diag_checkpoint,
        workers=args.diag_workers,
        label=args.diag_label,
        seed=args.diag_seed,
        device=args.diag_device,
        context_steps=args.diag_context_steps,
        expert_data=kinds(args.diag_expert_data),
        held_out=kinds(args.diag_held_out),
        compare=args.diag_compare,
        progress=not args.diag_no_progress,
        resume=not args.diag_fresh,
    )
    print((args.diag_out / SUMMARY_MD).read_text(), end="")
    print(f"diagnosis in {args.diag_out / SUMMARY_MD}")
    return 0


def _run_diagnose_pair(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.diagnose import load_diagnosis
    from navformer_rl.evaluation.diagnose.paired import paired_robot_trial_shares, paired_shares_markdown
    from navformer_rl.utils.durable import atomic_write_text

    out = _output_file(args.pair_out, "--out") if args.pair_out is not None else None
    names = tuple(load_diagnosis(folder)["label"] for folder in (args.pair_a, args.pair_b))
    shares = paired_robot_trial_shares(args.pair_a, args.pair_b, setups=args.pair_setups)
    table = paired_shares_markdown(names, shares)
    if out is not None:
        atomic_write_text(out, table)
    print(table, end="")
    return 0


def _run_probe(args: argparse.Namespace) -> int:
    from navformer_rl.evaluation.diagnose.probe import PROBE_MD, probe

    labels = [label for label, _ in args.probe_models]
    repeated = sorted({label for label in labels if labels.count(label) > 1})
    if repeated:
        raise ValueError(f"--model labels {repeated} repeat: expected one checkpoint per label")
    probe(
        dict(args.probe_models),
        args.probe_held_out,
        args.probe_out,
        max_trajectories=args.probe_max_trajectories,
        seed=args.probe_seed,
        device=args.probe_device,
        kind=args.probe_kind,
    )
    print((args.probe_out / PROBE_MD).read_text(), end="")
    print(f"probes in {args.probe_out / PROBE_MD}")
    return 0
