"""``diagnosis.md``: the failure measures of one or more diagnoses of the same episodes as markdown tables.

One column per diagnosis (its label); rows as in :mod:`~navformer_rl.evaluation.diagnose.measures`. The
experts' command distribution and the teacher-forced turns get their own tables, for the diagnoses that
measured them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.evaluation.diagnose.actions import HALF_FIELD_OF_VIEW
from navformer_rl.evaluation.diagnose.measures import (
    APPROACH_WINDOW,
    ARRIVAL_WINDOW,
    LARGE_TURN,
    LINGER_STEPS,
    OFF_CENTRE,
    OUTCOMES,
    SIGHTING_RANGES,
    TURN_CHANGE,
)

Render = Callable[[dict[str, Any]], str]
"""Renders one cell from a summary's ``all`` block."""


def _pct(value: Any) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"


def _num(digits: int) -> Callable[[Any], str]:
    return lambda value: "n/a" if value is None else f"{value:.{digits}f}"


def _cell(group: str, key: str, formatter: Callable[[Any], str]) -> Render:
    return lambda block: formatter(block[group][key])


def _pair(group: str, first: str, second: str, formatter: Callable[[Any], str]) -> Render:
    return lambda block: f"{formatter(block[group][first])} / {formatter(block[group][second])}"


def _sighting(index: int, key: str, formatter: Callable[[Any], str]) -> Render:
    def render(block: dict[str, Any]) -> str:
        entries = block["sightings"]
        return formatter(entries[index].get(key) if index < len(entries) else None)

    return render


def _other_targets(key: str) -> Render:
    return lambda block: _pct(block.get("other_targets", {}).get(key))  # n/a in older diagnoses


def _rows(summary: dict[str, Any]) -> list[tuple[str, Render]]:
    """``(row title, renderer)`` of the main table."""
    rows: list[tuple[str, Render]] = [
        ("robot-trials", lambda block: str(block["robot_trials"])),
        ("SR", lambda block: _pct(block["success_rate"])),
        (
            "failures: stuck / circling / other (of all)",
            lambda block: " / ".join(_pct(block["outcomes"][name]) for name in OUTCOMES[1:]),
        ),
        ("**walls**: in contact (of active steps)", _cell("walls", "contact_fraction", _pct)),
        ("of which with robots", _cell("walls", "robot_contact_share", _pct)),
        ("forward command touching / free", _pair("walls", "touching_forward", "free_forward", _num(2))),
        (
            "\\|turn\\| command touching / free",
            _pair("walls", "touching_abs_turn", "free_abs_turn", _num(2)),
        ),
        (
            "stuck at the end (of all / of failures)",
            _pair("walls", "stuck_fraction", "stuck_fraction_of_failures", _pct),
        ),
        ("steps to free after the first contact (median)", _cell("walls", "median_steps_to_free", _num(1))),
        ("never freed (of trials with contact)", _cell("walls", "never_freed_fraction", _pct)),
        (
            "**circling** at the end (of all / of failures)",
            _pair("circling", "circling_fraction", "circling_fraction_of_failures", _pct),
        ),
    ]
    for k, entry in enumerate(summary["all"]["sightings"]):
        rows += [
            (
                f"**target in view within {entry['range_m']:g} m**: robot-steps",
                _sighting(k, "sightings", str),
            ),
            (
                "robot-trials with such a sighting",
                _sighting(k, "robot_trials_with_sighting_fraction", _pct),
            ),
            ("first sighting at step (median of those)", _sighting(k, "first_sighting_step_median", _num(0))),
            ("SR of those", _sighting(k, "robot_trials_with_sighting_success_fraction", _pct)),
            (f"arrival within {ARRIVAL_WINDOW} steps (per sighting)", _sighting(k, "arrive_fraction", _pct)),
            (
                f"arrival within {ARRIVAL_WINDOW} steps (first sighting)",
                _sighting(k, "first_sighting_arrive_fraction", _pct),
            ),
            (
                f"distance change over the next {APPROACH_WINDOW} steps (m)",
                _sighting(k, "mean_distance_change", _num(2)),
            ),
            (
                f"turn command towards it when more than {math.degrees(OFF_CENTRE):g}° off the heading",
                _sighting(k, "turn_toward_fraction", _pct),
            ),
        ]
    rows += [
        (
            f"**other robots' targets**: active steps within {SUCCESS_RADIUS:g} m of one",
            _other_targets("near_step_fraction"),
        ),
        (f"robot-trials staying there {LINGER_STEPS}+ steps on end", _other_targets("lingered_fraction")),
        ("failures ending there", _other_targets("failures_ending_near_fraction")),
        ("**progress** along the shortest path per step (m)", _cell("progress", "per_step", _num(3))),
        ("driven per step (m)", _cell("progress", "driven_per_step", _num(3))),
        ("efficiency (progress / driven)", _cell("progress", "efficiency", _num(2))),
        ("steps closer / farther", _pair("progress", "closer_fraction", "farther_fraction", _pct)),
        (
            "per step, target visible / hidden (m)",
            _pair("progress", "per_step_target_visible", "per_step_target_hidden", _num(3)),
        ),
        ("net fraction of ℓ covered", _cell("progress", "net_fraction_of_l", _pct)),
        ("**commands**: angular std", lambda block: _num(3)(block["commands"]["angular"]["std"])),
        ("mean \\|angular\\|", lambda block: _num(3)(block["commands"]["angular"]["mean_abs"])),
        (
            f"\\|angular\\| > {LARGE_TURN:g}",
            lambda block: _pct(block["commands"]["angular"]["large_fraction"]),
        ),
        ("mean linear", lambda block: _num(3)(block["commands"]["linear"]["mean"])),
        (
            f"angular command changes by > {TURN_CHANGE:g} from the step before",
            lambda block: _pct(block["commands"]["angular"].get("change_fraction")),  # n/a in older diagnoses
        ),
        (
            "\\|angular\\| turned in each robot-trial's main direction (mean)",
            lambda block: _pct(block["commands"]["angular"].get("main_direction_share")),  # n/a in older ones
        ),
    ]
    return rows


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _phase_table(summaries: Sequence[dict[str, Any]]) -> list[str]:
    """The ``phases`` block as a table: one row per span of episode steps, one column per diagnosis
    (n/a for diagnoses written before the block existed)."""
    phased = next((s["all"]["phases"] for s in summaries if s["all"].get("phases")), None)
    if phased is None:
        return []

    def cell(summary: dict[str, Any], k: int) -> str:
        phases = summary["all"].get("phases")
        if not phases or k >= len(phases):
            return "n/a"
        p = phases[k]
        return (
            f"{_pct(p['contact_fraction'])}; {_num(2)(p['free_median_abs_turn'])} / "
            f"{_num(2)(p['touching_median_abs_turn'])}; {_pct(p['free_large_fraction'])}"
        )

    rows = [
        [
            f"{p['first_step']}-{p['last_step']}" if p["last_step"] is not None else f"{p['first_step']}-",
            *(cell(s, k) for s in summaries),
        ]
        for k, p in enumerate(phased)
    ]
    return [
        "",
        "## Commands by time in the episode",
        "",
        "Per span of active steps: in contact; median \\|turn\\| command free / touching (the previous step "
        f"ended in contact); free \\|turn\\| > {LARGE_TURN:g}",
        "",
        *_table(["steps", *(s["label"] for s in summaries)], rows),
    ]


def diagnosis_markdown(summaries: Sequence[dict[str, Any]]) -> str:
    """Markdown of ``summaries`` (``diagnosis.json`` contents of the same episode set), one column each."""
    first = summaries[0]
    episodes = first["episode_set"]
    lines = [
        f"# Diagnosis on {episodes['name']} ({episodes['episodes']} episodes, {episodes['max_steps']} steps)",
        "",
        'Every measured robot-trial, active steps only (`docs/evaluation.md`, "Diagnosing failures").',
        "",
    ]
    body = []
    for title, render in _rows(first):
        body.append([title, *(render(s["all"]) for s in summaries)])
    lines += _table(["measure", *(s["label"] for s in summaries)], body)

    lines += _phase_table(summaries)

    experts = next((s["expert_commands"] for s in summaries if s.get("expert_commands")), None)
    if experts:
        lines += ["", "## Commanded angular action: policies vs the experts' data", ""]
        columns = [(s["label"], s["all"]["commands"]) for s in summaries]
        columns += [(f"D_{kind}", stats) for kind, stats in experts.items()]
        rows = [
            ["std", *(_num(3)(c["angular"]["std"]) for _, c in columns)],
            ["mean \\|angular\\|", *(_num(3)(c["angular"]["mean_abs"]) for _, c in columns)],
            [f"\\|angular\\| > {LARGE_TURN:g}", *(_pct(c["angular"]["large_fraction"]) for _, c in columns)],
            [
                "\\|angular\\| quartiles / 90 %",
                *(" / ".join(_num(2)(q) for q in c["angular"]["abs_quantiles"] or []) for _, c in columns),
            ],
            [
                f"changes by > {TURN_CHANGE:g} from the step before",
                *(_pct(c["angular"].get("change_fraction")) for _, c in columns),
            ],
            ["actions", *(str(c["n"]) for _, c in columns)],
        ]
        lines += _table(["", *(name for name, _ in columns)], rows)

    forced = [(s["label"], s["teacher_forced"]) for s in summaries if s.get("teacher_forced")]
    if forced:
        lines += [
            "",
            "## Teacher-forced turns on held-out expert trajectories "
            f"(expert \\|angular\\| > {LARGE_TURN:g})",
            "",
        ]
        rows = [
            [
                f"{label}, D_{kind}",
                str(entry["large_turns"]),
                _num(3)(entry["mean_abs_expert"]),
                _num(3)(entry["mean_abs_predicted"]),
                _num(2)(entry["magnitude_ratio"]),
                _pct(entry["sign_agreement"]),
                _num(4)(entry["mse"]),
                _num(4)(entry["loss_dt"]),
            ]
            for label, result in forced
            for kind, entry in result.items()
        ]
        header = ["model, data", "steps", "mean \\|expert\\|", "mean \\|predicted\\|", "ratio", "same sign",
                  "angular MSE", "eq. 10 loss"]  # fmt: skip
        lines += _table(header, rows)
        lines += [
            "",
            f"Teacher-forced, the target in the camera's cone {math.degrees(OFF_CENTRE):g}-"
            f"{math.degrees(HALF_FIELD_OF_VIEW):g}° off the heading within {SIGHTING_RANGES[-1]:g} m (walls "
            "not checked): turn towards it",
            "",
        ]
        rows = [
            [
                f"{label}, D_{kind}",
                str(entry["edge_of_view"]["steps"]),
                _pct(entry["edge_of_view"]["expert_toward"]),
                _pct(entry["edge_of_view"]["predicted_toward"]),
                _pct(entry["edge_of_view"]["sign_agreement"]),
            ]
            for label, result in forced
            for kind, entry in result.items()
        ]
        lines += _table(["model, data", "steps", "expert", "predicted", "same sign"], rows)
        lines += [
            "",
            f"Teacher-forced where the expert's angular action changes by more than {TURN_CHANGE:g} from the "
            "step before (a model copying its previous action captures none of the change)",
            "",
        ]
        rows = [
            [
                f"{label}, D_{kind}",
                str(entry["turn_changes"]["steps"]),
                _num(2)(entry["turn_changes"]["captured"]),
                _pct(entry["turn_changes"]["moves_expert_way"]),
            ]
            for label, result in forced
            for kind, entry in result.items()
        ]
        lines += _table(["model, data", "steps", "change captured (median)", "moves the expert's way"], rows)
    return "\n".join(lines) + "\n"
