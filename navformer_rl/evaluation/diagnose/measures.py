"""Failure measures over recorded robot-trials (:class:`~navformer_rl.evaluation.diagnose.trace.RobotSteps`).

Every measure reads only a robot's *active* steps (up to and including its arrival) and only robots that
are measured (Table III's obstacle robots are left out by the caller). Step ``t``'s action is the policy's
answer to the observation at ``pose[t]``; ``contact[t]`` is what happened on that step.

- **walls**: the fraction of active steps in contact; for robot-trials with a contact, the mean commanded
  forward speed and ``|turn|`` (normalised actions) on steps taken *while touching* (the previous step
  ended in contact, so the camera shows the obstacle) against steps taken free; **stuck** robot-trials
  (failed, and over their last :data:`STUCK_WINDOW` active steps in contact on every step or never more than
  :data:`STUCK_DISPLACEMENT` from where the window began); **freeing**: steps from the first contact to the
  first step that begins :data:`FREE_STEPS` contact-free steps (or the arrival), median over those that free
  themselves, and the fraction that never do.
- **circling**: failed robot-trials whose last :data:`CIRCLE_WINDOW` steps stay within :data:`CIRCLE_RADIUS`
  of their mean position while driving more than :data:`CIRCLE_PATH` metres (``sum |v| dt``) and turning at
  least :data:`CIRCLE_TURN` net (``|sum w dt|``), which tells circling from dithering back and forth.
- **sightings**: robot-steps whose target is visible (camera fov and line of sight) within a range
  (:data:`SIGHTING_RANGES`); the fraction followed by arrival within :data:`ARRIVAL_WINDOW` steps, the mean
  change of the distance to the target over the next :data:`APPROACH_WINDOW` steps (negative = closer;
  cut at the trial's end), and the same for each robot-trial's first sighting; the median step of the
  first sighting (how long exploring took, over robot-trials that see their target) and the share of those
  robot-trials that succeed (SR = share with a sighting x this share + the rare successes without one:
  finding the target apart from reaching it); whether the target is
  recognised: on sightings with the target more than :data:`OFF_CENTRE` off the heading, the share of turn
  commands towards it (a policy that steers at the target it sees turns towards it; one that does not
  react to it turns either way about equally).
- **other targets**: over robot-trials whose world holds other robots' targets, the share of active steps
  within ``SUCCESS_RADIUS`` of another robot's target, the share of robot-trials that stay there for at least
  :data:`LINGER_STEPS` consecutive active steps, and the share of failed robot-trials that end there. A policy
  that takes another robot's target for its own drives to it and stays (it never arrives there); one that
  recognises its target passes by. In small mazes every robot passes others' targets often, and a failed
  robot-trial lasts the whole episode: the exploration expert (``frontier``), which detects only its own
  target, on the same episodes is the base rate.
- **progress**: geodesic progress ``geodesic[t] - geodesic[t+1]`` (positive = closer along the shortest
  path): per active step, per metre driven (efficiency: 1 = every metre brings the robot a metre closer,
  ~0 = wandering), split by whether the target was visible, and the net fraction of ℓ covered.
- **commands**: the distribution of the commanded actions (:func:`command_statistics`).
- **phases**: the same per span of episode steps (:data:`EPISODE_PHASES`): active robot-steps, the fraction
  in contact, and the median ``|turn|`` commanded free and while touching (as in **walls**) and the share of
  large free turns. A policy whose turns fade as its context fills shows it here, apart from the walls.
- **outcomes**: the share of robot-trials that succeeded, ended stuck, ended circling, or failed otherwise
  (:func:`outcome`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.evaluation.diagnose.trace import RobotSteps

LINGER_STEPS = 50
"""Consecutive active steps (10 s) within ``SUCCESS_RADIUS`` of another robot's target from which a
robot-trial counts as lingering there."""
STUCK_WINDOW = 50
STUCK_DISPLACEMENT = 0.1
FREE_STEPS = 5
CIRCLE_WINDOW = 100
CIRCLE_RADIUS = 1.0
CIRCLE_PATH = 5.0
CIRCLE_TURN = math.pi
"""Net turn (radians) of a circling window: a circle of at most 1 m radius driven for 5 m turns >= 5 rad;
random walking (VRW) within the disc turns ~1.7 rad (one standard deviation) over 100 steps."""
SIGHTING_RANGES = (3.0, 6.0)
ARRIVAL_WINDOW = 30
APPROACH_WINDOW = 10
PROGRESS_EPS = 0.01
"""Metres of geodesic change per step below which a step counts as neither closer nor farther."""
OFF_CENTRE = math.radians(30.0)
"""Bearing (radians) beyond which a target in view calls for a turn towards it: the outer third of the 90°
camera's half-field; nearer the centre even the privileged FCA, following its planned path, turns towards
the target little more often than away (56 % at 10°, 76 % beyond 30° on the 40 medium trials)."""
LARGE_TURN = 0.5
"""``|angular action|`` (normalised) above which a command counts as a large turn."""
HISTOGRAM_BINS = 20
TURN_CHANGE = 0.3
"""Change of the angular action from one step to the next above which a step counts as a turn change."""
EPISODE_PHASES = (0, 25, 50, 100, 150, 200, 250, 300, 400)
"""First step of each span of :func:`phase_measures`; the last span runs to the end of the trial."""


def _ratio(numerator: float, denominator: float) -> float | None:
    return float(numerator) / float(denominator) if denominator else None


def _mean(values) -> float | None:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(values.mean()) if values.size else None


def is_stuck(robot: RobotSteps, window: int = STUCK_WINDOW, displacement: float = STUCK_DISPLACEMENT) -> bool:
    """Whether a failed robot-trial ends stuck: over its last ``window`` active steps it was in contact on
    every step, or it never got ``displacement`` metres from where the window began."""
    if robot.success or robot.n < window:
        return False
    if robot.contact[-window:].all():
        return True
    xy = robot.pose[-window - 1 :, :2]
    return float(np.hypot(*(xy - xy[0]).T).max()) < displacement


def is_circling(
    robot: RobotSteps,
    window: int = CIRCLE_WINDOW,
    radius: float = CIRCLE_RADIUS,
    path: float = CIRCLE_PATH,
    turn: float = CIRCLE_TURN,
) -> bool:
    """Whether a failed robot-trial ends circling: its last ``window`` steps stay within ``radius`` metres of
    their mean position while it drives more than ``path`` metres and turns by at least ``turn`` radians net
    (``|sum w dt|``; driving back and forth on the spot turns little)."""
    if robot.success or robot.n < window:
        return False
    xy = robot.pose[-window - 1 :, :2]
    spread = float(np.hypot(*(xy - xy.mean(axis=0)).T).max())
    turned = abs(float(robot.velocity[-window:, 1].sum()) * robot.dt)
    return spread <= radius and float(robot.driven[-window:].sum()) > path and turned >= turn


def steps_to_free(robot: RobotSteps, free_steps: int = FREE_STEPS) -> int | None:
    """Steps from the first contact to the first step that begins ``free_steps`` contact-free steps (or
    the trial's end when the robot arrived: arriving frees it); None when it never frees itself or never
    touched anything (check ``robot.contact.any()``)."""
    hits = np.flatnonzero(robot.contact)
    if hits.size == 0:
        return None
    first = int(hits[0])
    for start in range(first + 1, robot.n + 1):
        run = robot.contact[start : start + free_steps]
        if not run.any() and (run.size == free_steps or robot.success):
            return start - first
    return None


def wall_measures(robots: Sequence[RobotSteps]) -> dict[str, Any]:
    """The ``walls`` block of the summary (module docstring)."""
    active = sum(r.n for r in robots)
    contact_steps = sum(int(r.contact.sum()) for r in robots)
    robot_contacts = sum(int(r.robot_contact.sum()) for r in robots if r.robot_contact is not None)
    touched = [r for r in robots if r.contact.any()]
    touching_cmd, free_cmd = [], []
    for r in touched:
        touching = np.concatenate([[False], r.contact[:-1]])  # the previous step ended in contact
        touching_cmd.append(r.action[touching])
        free_cmd.append(r.action[~touching])
    touching_cmd = np.concatenate(touching_cmd) if touching_cmd else np.zeros((0, 2))
    free_cmd = np.concatenate(free_cmd) if free_cmd else np.zeros((0, 2))
    freed = [steps_to_free(r) for r in touched]
    freed_steps = [s for s in freed if s is not None]
    failures = [r for r in robots if not r.success]
    stuck = sum(is_stuck(r) for r in robots)
    return {
        "contact_fraction": _ratio(contact_steps, active),
        "robot_contact_share": _ratio(robot_contacts, contact_steps),
        "robot_trials_with_contact": len(touched),
        "touching_forward": _mean(touching_cmd[:, 0]),
        "touching_abs_turn": _mean(np.abs(touching_cmd[:, 1])),
        "free_forward": _mean(free_cmd[:, 0]),
        "free_abs_turn": _mean(np.abs(free_cmd[:, 1])),
        "stuck_fraction": _ratio(stuck, len(robots)),
        "stuck_fraction_of_failures": _ratio(stuck, len(failures)),
        "median_steps_to_free": float(np.median(freed_steps)) if freed_steps else None,
        "never_freed_fraction": _ratio(len(freed) - len(freed_steps), len(touched)),
    }


def circling_measures(robots: Sequence[RobotSteps]) -> dict[str, Any]:
    """The ``circling`` block of the summary (module docstring)."""
    circling = sum(is_circling(r) for r in robots)
    failures = sum(not r.success for r in robots)
    return {
        "circling_fraction": _ratio(circling, len(robots)),
        "circling_fraction_of_failures": _ratio(circling, failures),
    }


def sightings(robot: RobotSteps, max_range: float) -> np.ndarray:
    """int ``[k]``: the active steps ``t`` whose observation shows the target within ``max_range`` metres."""
    seen = robot.visible[: robot.n] & (robot.distance[: robot.n] <= max_range)
    return np.flatnonzero(seen)


def bearing_to(pose: np.ndarray, target: np.ndarray) -> np.ndarray:
    """float ``[N]``: the angle from the heading of ``pose`` ``(x, y, yaw)`` ``[N, 3]`` to ``target``
    (``[2]`` or ``[N, 2]``), in ``[-pi, pi]`` (positive: to the left, where a positive turn command goes)."""
    pose = np.asarray(pose, dtype=np.float64)
    offset = np.asarray(target, dtype=np.float64)[..., :2] - pose[:, :2]
    angle = np.arctan2(offset[:, 1], offset[:, 0]) - pose[:, 2]
    return np.arctan2(np.sin(angle), np.cos(angle))


def bearing(robot: RobotSteps) -> np.ndarray:
    """float ``[n+1]``: :func:`bearing_to` the robot's target at each pose; NaN without ``robot.target``."""
    if robot.target is None:
        return np.full(robot.pose.shape[0], np.nan)
    return bearing_to(robot.pose, robot.target)


def sighting_measures(
    robots: Sequence[RobotSteps],
    ranges: Sequence[float] = SIGHTING_RANGES,
    arrival: int = ARRIVAL_WINDOW,
    approach: int = APPROACH_WINDOW,
) -> list[dict[str, Any]]:
    """The ``sightings`` block of the summary: one entry per range (module docstring)."""
    blocks = []
    for max_range in ranges:
        arrived, change, first_arrived, first_step, succeeded, toward = [], [], [], [], [], []
        for r in robots:
            steps = sightings(r, max_range)
            if steps.size == 0:
                continue
            arrives = np.full(steps.shape, r.success) & (r.n - steps <= arrival)
            arrived.append(arrives)
            change.append(r.distance[np.minimum(steps + approach, r.n)] - r.distance[steps])
            first_arrived.append(bool(arrives[0]))
            first_step.append(int(steps[0]))
            succeeded.append(bool(r.success))
            if r.target is not None:
                acting = steps[steps < r.n]  # a sighting at the last pose has no command
                off = bearing(r)[acting]
                off_centre = np.abs(off) > OFF_CENTRE
                toward.append(r.action[acting[off_centre], 1] * off[off_centre] > 0)
        arrived = np.concatenate(arrived) if arrived else np.zeros(0, dtype=bool)
        change = np.concatenate(change) if change else np.zeros(0)
        toward = np.concatenate(toward) if toward else np.zeros(0, dtype=bool)
        blocks.append(
            {
                "range_m": float(max_range),
                "sightings": int(arrived.size),
                "arrive_fraction": _mean(arrived),
                "mean_distance_change": _mean(change),
                "robot_trials_with_sighting": len(first_arrived),
                "robot_trials_with_sighting_fraction": _ratio(len(first_arrived), len(robots)),
                "first_sighting_arrive_fraction": _mean(first_arrived),
                "first_sighting_step_median": float(np.median(first_step)) if first_step else None,
                "robot_trials_with_sighting_success_fraction": _mean(succeeded),
                "off_centre_sightings": int(toward.size),
                "turn_toward_fraction": _mean(toward),
            }
        )
    return blocks


def near_other_target(robot: RobotSteps) -> np.ndarray:
    """bool ``[n+1]``: the poses within ``SUCCESS_RADIUS`` of another robot's target (all False without
    ``robot.other_targets``)."""
    if robot.other_targets is None or not len(robot.other_targets):
        return np.zeros(robot.pose.shape[0], dtype=bool)
    offset = robot.pose[:, None, :2] - np.asarray(robot.other_targets)[None, :, :2]  # [n+1, k, 2]
    return (np.hypot(offset[..., 0], offset[..., 1]) <= SUCCESS_RADIUS).any(axis=1)


def longest_run(flags: np.ndarray) -> int:
    """The length of the longest run of consecutive True values in bool ``flags`` ``[n]`` (0 without one)."""
    edges = np.diff(np.r_[0, np.asarray(flags, dtype=np.int8), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int((ends - starts).max()) if starts.size else 0


def other_target_measures(robots: Sequence[RobotSteps], linger: int = LINGER_STEPS) -> dict[str, Any]:
    """The ``other_targets`` block of the summary (module docstring)."""
    robots = [r for r in robots if r.other_targets is not None and len(r.other_targets)]
    near = [near_other_target(r)[: r.n] for r in robots]  # active steps
    failed = [r for r in robots if not r.success]
    return {
        "robot_trials": len(robots),
        "near_step_fraction": _ratio(sum(int(m.sum()) for m in near), sum(r.n for r in robots)),
        "lingered_fraction": _mean([longest_run(m) >= linger for m in near]),
        "failures": len(failed),
        "failures_ending_near_fraction": _mean([bool(near_other_target(r)[-1]) for r in failed]),
    }


def progress_measures(robots: Sequence[RobotSteps], eps: float = PROGRESS_EPS) -> dict[str, Any]:
    """The ``progress`` block of the summary (module docstring)."""
    progress, driven, visible, net = [], [], [], []
    for r in robots:
        step = r.geodesic[:-1] - r.geodesic[1:]
        finite = np.isfinite(step)  # a cell cut off from the target (inf) says nothing
        progress.append(step[finite])
        driven.append(r.driven[finite])
        visible.append(r.visible[: r.n][finite])
        if math.isfinite(r.geodesic[0]) and math.isfinite(r.geodesic[-1]) and r.geodesic[0] > 0:
            net.append((r.geodesic[0] - r.geodesic[-1]) / r.geodesic[0])
    progress = np.concatenate(progress) if progress else np.zeros(0)
    driven = np.concatenate(driven) if driven else np.zeros(0)
    visible = np.concatenate(visible) if visible else np.zeros(0, dtype=bool)
    return {
        "per_step": _mean(progress),
        "driven_per_step": _mean(driven),
        "efficiency": _ratio(progress.sum(), driven.sum()),
        "closer_fraction": _mean(progress > eps),
        "farther_fraction": _mean(progress < -eps),
        "per_step_target_visible": _mean(progress[visible]),
        "per_step_target_hidden": _mean(progress[~visible]),
        "net_fraction_of_l": _mean(net),
    }


def command_statistics(
    actions: np.ndarray, bins: int = HISTOGRAM_BINS, starts: np.ndarray | None = None
) -> dict[str, Any]:
    """Distribution of normalised actions ``[N, 2]`` (linear, angular), per component: ``mean``, ``std``,
    ``mean_abs``, ``abs_quantiles`` (25 / 50 / 75 / 90 %), ``large_fraction`` (``|a| >`` :data:`LARGE_TURN`)
    and ``histogram`` (fractions of the ``N`` actions in ``bins`` equal bins over [-1, 1]); and
    ``change_fraction``: the share of consecutive actions of one sequence whose component changes by more
    than :data:`TURN_CHANGE` (``starts`` bool ``[N]`` marks each sequence's first action; None: one
    sequence). A policy that keeps repeating its last command changes it rarely. The angular block adds
    ``main_direction_share``: per sequence, the share of its summed ``|angular|`` turned in its main direction
    (``(1 + |sum a| / sum |a|) / 2``: 0.5 as much left as right, 1 only one way), averaged over the sequences
    that turn at all (None without one). A policy circling one way scores near 1; the experts' trials score
    0.74-0.76 on the 40 trials of ``docs/studies.md``."""
    actions = np.asarray(actions, dtype=np.float64).reshape(-1, 2)
    follows = np.ones(actions.shape[0], dtype=bool) if starts is None else ~np.asarray(starts, dtype=bool)
    follows[:1] = False
    out: dict[str, Any] = {"n": int(actions.shape[0])}
    for k, name in enumerate(("linear", "angular")):
        values = np.clip(actions[:, k], -1.0, 1.0)
        counts, _ = np.histogram(values, bins=bins, range=(-1.0, 1.0))
        size = max(values.size, 1)
        out[name] = {
            "mean": _mean(values),
            "std": float(values.std()) if values.size else None,
            "mean_abs": _mean(np.abs(values)),
            "abs_quantiles": (
                [float(q) for q in np.quantile(np.abs(values), [0.25, 0.5, 0.75, 0.9])]
                if values.size
                else None
            ),
            "large_fraction": _mean(np.abs(values) > LARGE_TURN),
            "change_fraction": _mean((np.abs(np.diff(values, prepend=0.0)) > TURN_CHANGE)[follows]),
            "histogram": [round(float(c) / size, 6) for c in counts],
        }
    out["angular"]["main_direction_share"] = main_direction_share(actions[:, 1], ~follows)
    return out


def main_direction_share(angular: np.ndarray, starts: np.ndarray) -> float | None:
    """Mean over the sequences of ``angular`` (``starts`` bool marks each one's first step) that turn at all
    of the share of their summed ``|angular|`` in their main direction (see :func:`command_statistics`)."""
    if angular.size == 0:
        return None
    starts = np.asarray(starts, dtype=bool).copy()
    starts[0] = True
    sequence = np.cumsum(starts) - 1
    count = int(sequence[-1]) + 1
    signed = np.bincount(sequence, weights=np.clip(angular, -1.0, 1.0), minlength=count)
    total = np.bincount(sequence, weights=np.abs(np.clip(angular, -1.0, 1.0)), minlength=count)
    turning = total > 0
    return _mean((1.0 + np.abs(signed[turning]) / total[turning]) / 2.0) if turning.any() else None


def phase_measures(
    robots: Sequence[RobotSteps], starts: Sequence[int] = EPISODE_PHASES
) -> list[dict[str, Any]]:
    """The ``phases`` block: per span ``[starts[k], starts[k + 1])`` of active steps (the last one open),
    ``first_step``, ``last_step`` (None: open), ``robot_steps``, ``contact_fraction``,
    ``free_median_abs_turn``, ``free_large_fraction`` (``|turn| >`` :data:`LARGE_TURN`) and
    ``touching_median_abs_turn`` (steps taken while the previous step ended in contact, as in
    :func:`wall_measures`); None where a span has no such step."""
    step = np.concatenate([np.arange(r.n) for r in robots]) if robots else np.zeros(0, dtype=int)
    contact = np.concatenate([r.contact for r in robots]) if robots else np.zeros(0, dtype=bool)
    touching = (
        np.concatenate([np.concatenate([[False], r.contact[:-1]]) for r in robots])
        if robots
        else np.zeros(0, dtype=bool)
    )
    turn = np.abs(np.concatenate([r.action[:, 1] for r in robots])) if robots else np.zeros(0)
    out = []
    for k, first in enumerate(starts):
        last = starts[k + 1] - 1 if k + 1 < len(starts) else None
        inside = (step >= first) & (step <= (last if last is not None else np.inf))
        free, held = turn[inside & ~touching], turn[inside & touching]
        out.append(
            {
                "first_step": int(first),
                "last_step": last,
                "robot_steps": int(inside.sum()),
                "contact_fraction": _mean(contact[inside]),
                "free_median_abs_turn": float(np.median(free)) if free.size else None,
                "free_large_fraction": _mean(free > LARGE_TURN),
                "touching_median_abs_turn": float(np.median(held)) if held.size else None,
            }
        )
    return out


OUTCOMES = ("success", "stuck", "circling", "other failure")


def outcome(robot: RobotSteps) -> str:
    """How a robot-trial ended, one of :data:`OUTCOMES` (stuck is checked before circling; they exclude each
    other anyway: circling drives more than 5 m in its window, stuck never leaves 0.1 m or stays in
    contact)."""
    if robot.success:
        return "success"
    if is_stuck(robot):
        return "stuck"
    return "circling" if is_circling(robot) else "other failure"


def robot_row(robot: RobotSteps) -> dict[str, Any]:
    """One robot-trial's diagnosis in brief (a row of ``robot_trials.jsonl``)."""
    hits = np.flatnonzero(robot.contact)
    seen = sightings(robot, SIGHTING_RANGES[0])
    return {
        "outcome": outcome(robot),
        "steps": robot.n,
        "contact_steps": int(robot.contact.sum()),
        "first_contact_step": int(hits[0]) if hits.size else None,
        "steps_to_free": steps_to_free(robot),
        "first_sighting_step": int(seen[0]) if seen.size else None,
        "steps_near_other_target": int(near_other_target(robot)[: robot.n].sum()),
        "geodesic_start": float(robot.geodesic[0]),
        "geodesic_end": float(robot.geodesic[-1]),
        "path_driven": float(robot.driven.sum()),
    }


def summarize_robots(robots: Sequence[RobotSteps]) -> dict[str, Any]:
    """Every block of the diagnosis summary over measured robot-trials ``robots``."""
    actions = np.concatenate([r.action for r in robots]) if robots else np.zeros((0, 2))
    starts = np.zeros(actions.shape[0], dtype=bool)
    starts[np.cumsum([0] + [r.n for r in robots[:-1]])[: len(robots)]] = True
    return {
        "robot_trials": len(robots),
        "active_steps": int(sum(r.n for r in robots)),
        "success_rate": _mean([r.success for r in robots]),
        "outcomes": {name: _mean([outcome(r) == name for r in robots]) for name in OUTCOMES},
        "walls": wall_measures(robots),
        "circling": circling_measures(robots),
        "sightings": sighting_measures(robots),
        "other_targets": other_target_measures(robots),
        "progress": progress_measures(robots),
        "commands": command_statistics(actions, starts=starts),
        "phases": phase_measures(robots),
    }
