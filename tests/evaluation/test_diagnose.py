"""``navformer evaluate diagnose``: failure measures on hand-built robot-trials (known answers), the camera's
view of the target, and small end-to-end runs (VRW, an untrained NavFormer) against the evaluation."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from navformer_rl.evaluation.diagnose.actions import edge_of_view_turns, turn_agreement, turn_changes
from navformer_rl.evaluation.diagnose.measures import (
    bearing,
    command_statistics,
    is_circling,
    is_stuck,
    main_direction_share,
    outcome,
    phase_measures,
    progress_measures,
    sighting_measures,
    steps_to_free,
    wall_measures,
)
from navformer_rl.evaluation.diagnose.trace import EpisodeGeometry, RobotSteps, load_trace, save_trace

DT = 0.2


def robot(xy, *, contact=None, action=None, speed=None, success=False, target=(100.0, 0.0), visible=None):
    """A :class:`RobotSteps` through the positions ``xy`` ``[n+1, 2]``; distance and geodesic are the straight
    line to ``target``; executed speed: the displacement per step unless ``speed`` ``[n]`` is given."""
    xy = np.asarray(xy, dtype=np.float64)
    n = len(xy) - 1
    step = np.diff(xy, axis=0)
    yaw = np.append(np.arctan2(step[:, 1], step[:, 0]), 0.0)
    distance = np.hypot(*(xy - np.asarray(target)).T)
    v = np.hypot(*step.T) / DT if speed is None else np.asarray(speed, dtype=np.float64)
    w = np.diff(np.unwrap(np.r_[yaw[0], yaw[:-1]])) / DT  # turning between step directions
    return RobotSteps(
        pose=np.column_stack([xy, yaw]),
        action=np.zeros((n, 2)) if action is None else np.asarray(action, dtype=np.float64),
        velocity=np.column_stack([v, w]),
        contact=np.zeros(n, dtype=bool) if contact is None else np.asarray(contact, dtype=bool),
        distance=distance,
        geodesic=distance.copy(),
        visible=np.zeros(n + 1, dtype=bool) if visible is None else np.asarray(visible, dtype=bool),
        success=success,
        dt=DT,
    )


def straight(n: int, start=(0.0, 0.0), step=0.1) -> np.ndarray:
    """``n`` steps of ``step`` metres along +x from ``start``."""
    return np.column_stack([start[0] + step * np.arange(n + 1), np.full(n + 1, start[1])])


def pinned_at_wall() -> RobotSteps:
    """100 steps: 40 driving free, then 60 pushed into a wall (no motion, full forward, no turn)."""
    xy = np.vstack([straight(40), np.repeat(straight(40)[-1:], 60, axis=0)])
    contact = np.r_[np.zeros(40, bool), np.ones(60, bool)]
    action = np.column_stack([np.full(100, 0.9), np.r_[np.full(40, 0.4), np.zeros(60)]])
    return robot(xy, contact=contact, action=action)


# --------------------------------------------------------------------------------------------- walls


def test_a_robot_pinned_at_a_wall_for_its_last_60_steps_is_stuck_and_never_frees_itself():
    pinned = pinned_at_wall()
    assert is_stuck(pinned)
    assert steps_to_free(pinned) is None
    walls = wall_measures([pinned, robot(straight(100))])
    assert walls["contact_fraction"] == pytest.approx(60 / 200)
    assert walls["robot_trials_with_contact"] == 1
    # commands issued while touching: the 59 steps after the first contact step
    assert walls["touching_forward"] == pytest.approx(0.9)
    assert walls["touching_abs_turn"] == pytest.approx(0.0)
    assert walls["free_abs_turn"] == pytest.approx(0.4 * 40 / 41)  # 40 free steps turning, 1 (the hit) not
    assert walls["stuck_fraction"] == pytest.approx(0.5)
    assert walls["stuck_fraction_of_failures"] == pytest.approx(0.5)
    assert walls["never_freed_fraction"] == 1.0
    assert walls["median_steps_to_free"] is None


def test_a_robot_that_backs_off_a_wall_frees_itself_and_is_not_stuck():
    contact = np.zeros(100, bool)
    contact[[20, 21, 22, 30]] = True  # three steps in contact, free for 7, one more touch
    moving = robot(straight(100), contact=contact)
    assert steps_to_free(moving) == 3
    assert not is_stuck(moving)
    walls = wall_measures([moving])
    assert walls["median_steps_to_free"] == 3.0 and walls["never_freed_fraction"] == 0.0


def test_arriving_while_in_contact_counts_as_freed_and_arrival_is_never_stuck():
    contact = np.r_[np.zeros(97, bool), np.ones(3, bool)]
    arrived = robot(straight(100), contact=contact, success=True)
    assert steps_to_free(arrived) == 3
    assert not is_stuck(robot(np.zeros((101, 2)), success=True))


def test_standing_still_without_contact_for_50_steps_is_stuck():
    xy = np.vstack([straight(50), straight(50)[-1:] + np.linspace(0, 0.05, 51)[1:, None] * [1, 0]])
    assert is_stuck(robot(xy))
    xy[-1] += [0.2, 0.0]  # one step out of the 0.1 m disc
    assert not is_stuck(robot(xy))


# ------------------------------------------------------------------------------------------ circling


def test_a_circling_trace_is_circling_and_driving_on_or_spinning_in_place_is_not():
    angles = np.arange(121) * 0.2  # 0.1 m of arc per step on a 0.5 m circle: 12 m in 120 steps
    circle = np.column_stack([5 + 0.5 * np.cos(angles), 5 + 0.5 * np.sin(angles)])
    circling = robot(circle, speed=np.full(120, 0.5))
    assert is_circling(circling)
    assert not is_stuck(circling)
    assert not is_circling(robot(straight(120)))
    spinning = robot(np.repeat([[5.0, 5.0]], 121, axis=0), action=np.tile([0.0, 1.0], (120, 1)))
    assert not is_circling(spinning)  # no path driven: stuck, not circling
    assert is_stuck(spinning)
    assert not is_circling(robot(circle, speed=np.full(120, 0.5), success=True))
    # back and forth along 0.3 m, 36 m of path: dithering on the spot, no net turn
    dither = np.column_stack([5 + 0.3 * (np.arange(121) % 2), np.full(121, 5.0)])
    dithering = robot(dither)
    dithering.velocity[:, 1] = 0.0  # forward and back without turning
    assert not is_circling(dithering) and not is_stuck(dithering)


def test_each_robot_trial_gets_one_outcome():
    angles = np.arange(121) * 0.2
    circle = np.column_stack([5 + 0.5 * np.cos(angles), 5 + 0.5 * np.sin(angles)])
    assert outcome(pinned_at_wall()) == "stuck"
    assert outcome(robot(circle, speed=np.full(120, 0.5))) == "circling"
    assert outcome(robot(straight(120))) == "other failure"
    assert outcome(robot(straight(120), success=True)) == "success"


# ------------------------------------------------------------------------------------- other targets


def test_lingering_at_another_robots_target_is_told_from_passing_by():
    from dataclasses import replace

    from navformer_rl.evaluation.diagnose.measures import (
        longest_run,
        near_other_target,
        other_target_measures,
    )

    others = np.array([[2.0, 0.0], [50.0, 50.0]])
    passing = replace(robot(straight(60)), other_targets=others)  # 0.1 m a step past (2, 0): x in [0.5, 3.5]
    parked = np.vstack([straight(20), np.repeat(straight(20)[-1:], 40, axis=0)])  # stops at (2, 0): 55 steps
    lingering = replace(robot(parked), other_targets=others)
    arriving = replace(robot(straight(10, start=(0.0, 10.0)), success=True), other_targets=others)  # far
    alone = robot(straight(60))  # no other robot's target known: left out
    assert near_other_target(passing)[:61].sum() == 31 and near_other_target(alone).sum() == 0
    block = other_target_measures([passing, lingering, arriving, alone])
    assert block["robot_trials"] == 3 and block["failures"] == 2
    near = 31 + 55  # active steps (the last pose has no step): passing t = 5..35, lingering t = 5..59
    assert block["near_step_fraction"] == pytest.approx(near / (60 + 60 + 10))
    assert block["lingered_fraction"] == pytest.approx(1 / 3)  # passing stays 31 steps: < 50
    assert block["failures_ending_near_fraction"] == pytest.approx(0.5)  # lingering ends there, passing not
    assert other_target_measures([passing], linger=31)["lingered_fraction"] == 1.0
    assert other_target_measures([passing], linger=32)["lingered_fraction"] == 0.0
    assert [longest_run(np.array(f, bool)) for f in ([], [0, 0], [1, 1, 0, 1], [0, 1, 1, 1])] == [0, 0, 2, 3]
    assert other_target_measures([alone]) == {
        "robot_trials": 0,
        "near_step_fraction": None,
        "lingered_fraction": None,
        "failures": 0,
        "failures_ending_near_fraction": None,
    }


# ----------------------------------------------------------------------------------------- sightings


def test_a_sighting_followed_by_arrival_is_counted_with_its_approach():
    # 26 steps of 0.1 m towards a target 4 m ahead, arriving at 1.4 m; the target is in view throughout
    target = (4.0, 0.0)
    arriving = robot(straight(26), success=True, target=target, visible=np.ones(27, bool))
    lost = robot(straight(26), success=False, target=target, visible=np.ones(27, bool))
    three, six = sighting_measures([arriving, lost], ranges=(3.0, 6.0))
    # within 3 m: steps t = 10..25 (distance 3.0 .. 1.5) of both robots
    assert three["sightings"] == 32 and three["robot_trials_with_sighting"] == 2
    assert three["arrive_fraction"] == pytest.approx(0.5)
    assert three["first_sighting_arrive_fraction"] == pytest.approx(0.5)
    assert three["first_sighting_step_median"] == 10.0  # 3.0 m from the target after 10 steps of 0.1 m
    assert three["robot_trials_with_sighting_success_fraction"] == 0.5
    # over the next 10 steps: -1.0 m while the trial lasts 10 more steps (t <= 16), else to the end
    change = [-0.1 * min(10, 26 - t) for t in range(10, 26)]
    assert three["mean_distance_change"] == pytest.approx(np.mean(change))
    assert six["sightings"] == 52  # every active step (4.0 m .. 1.5 m)
    assert six["arrive_fraction"] == pytest.approx(0.5)


def test_a_target_out_of_view_is_no_sighting():
    hidden = robot(straight(26), success=True, target=(4.0, 0.0))
    (block,) = sighting_measures([hidden], ranges=(3.0,))
    assert block["sightings"] == 0 and block["arrive_fraction"] is None
    assert block["robot_trials_with_sighting_fraction"] == 0.0
    assert block["first_sighting_step_median"] is None
    assert block["robot_trials_with_sighting_success_fraction"] is None


def test_arrival_later_than_30_steps_after_a_sighting_does_not_count():
    target = (6.0, 0.0)
    visible = np.zeros(46, bool)
    visible[10] = True  # 5.0 m away, seen once; arrives 35 steps later
    slow = robot(straight(45), success=True, target=target, visible=visible)
    (block,) = sighting_measures([slow], ranges=(6.0,))
    assert block["sightings"] == 1 and block["arrive_fraction"] == 0.0


def test_bearing_is_the_signed_angle_from_the_heading_to_the_target():
    # driving along +x (heading 0): a target ahead-left at 45 degrees, then one behind-right
    ahead_left = dataclasses.replace(robot(straight(2)), target=np.array([1.0, 1.0]))
    assert bearing(ahead_left)[0] == pytest.approx(math.pi / 4)
    behind_right = dataclasses.replace(robot(straight(2)), target=np.array([-1.0, -1.0]))
    assert bearing(behind_right)[0] == pytest.approx(-3 * math.pi / 4)
    assert np.isnan(bearing(robot(straight(2)))).all()  # no target known


def test_turning_towards_a_target_in_view_is_counted_only_when_it_is_off_centre():
    # a target 2 m away at 45 degrees to the left, in view for 10 steps while the robot stands still
    xy = np.zeros((11, 2))
    visible = np.ones(11, bool)
    left = np.column_stack([np.zeros(10), np.r_[np.full(7, 0.5), np.full(3, -0.5)]])  # 7 left, 3 right
    seen = dataclasses.replace(
        robot(xy, action=left, visible=visible, target=(math.sqrt(2), math.sqrt(2))),
        target=np.array([math.sqrt(2), math.sqrt(2)]),
    )
    (block,) = sighting_measures([seen], ranges=(3.0,))
    assert block["off_centre_sightings"] == 10 and block["turn_toward_fraction"] == pytest.approx(0.7)
    # dead ahead: no turn is called for
    ahead = dataclasses.replace(seen, target=np.array([2.0, 0.0]), distance=np.full(11, 2.0))
    (block,) = sighting_measures([ahead], ranges=(3.0,))
    assert block["off_centre_sightings"] == 0 and block["turn_toward_fraction"] is None
    # without the target's position the measure is unknown, the others stay
    (block,) = sighting_measures([dataclasses.replace(seen, target=None)], ranges=(3.0,))
    assert block["turn_toward_fraction"] is None and block["sightings"] == 10


def test_teacher_forced_turns_at_the_edge_of_view_count_only_targets_in_the_cone_near_its_edge():
    # heading +x from the origin; targets at 40° left (in the edge band), 5° (centre), 60° (outside the
    # 90° view), and 40° left but 8 m away (beyond 6 m)
    def at(degrees, metres):
        return [metres * math.cos(math.radians(degrees)), metres * math.sin(math.radians(degrees))]

    target = np.array([at(40, 2), at(40, 2), at(40, 2), at(40, 2), at(5, 2), at(60, 2), at(40, 8)])
    pose = np.zeros((7, 3))
    expert = np.array([0.8, 0.8, 0.8, -0.8, 0.8, 0.8, 0.8])  # turns left (towards) on 3 of the 4 edge steps
    predicted = np.array([0.5, -0.5, -0.5, -0.5, 0.5, 0.5, 0.5])  # towards on 1 of 4
    result = edge_of_view_turns(predicted, expert, pose, target)
    assert result["steps"] == 4
    assert result["expert_toward"] == pytest.approx(0.75) and result["predicted_toward"] == pytest.approx(
        0.25
    )
    assert result["sign_agreement"] == pytest.approx(0.5)  # steps 0 and 3
    assert edge_of_view_turns(predicted[4:], expert[4:], pose[4:], target[4:])["steps"] == 0


def test_turn_changes_tell_following_the_expert_from_copying_the_previous_action():
    nan = float("nan")
    previous = np.array([0.0, 0.0, 0.5, 0.5, 0.2, nan])
    expert = np.array([0.6, -0.6, -0.5, 0.0, 0.3, 0.9])  # changes of 0.6, -0.6, -1.0, -0.5; then 0.1, none
    predicted = np.array([0.6, 0.0, 0.0, 0.6, 0.3, 0.9])  # all, none, half, the wrong way
    result = turn_changes(predicted, expert, previous)
    assert result["steps"] == 4
    assert result["captured"] == pytest.approx(0.25)  # median of 1, 0, 0.5, -0.2
    assert result["moves_expert_way"] == pytest.approx(0.5)
    assert turn_changes(predicted[4:], expert[4:], previous[4:])["steps"] == 0


# ------------------------------------------------------------------------------------------ progress


def test_progress_tells_a_straight_approach_from_wandering():
    approach = progress_measures([robot(straight(20), target=(10.0, 0.0))])
    assert approach["per_step"] == pytest.approx(0.1)
    assert approach["efficiency"] == pytest.approx(1.0)
    assert approach["closer_fraction"] == 1.0 and approach["farther_fraction"] == 0.0
    assert approach["net_fraction_of_l"] == pytest.approx(0.2)
    # back and forth across a line perpendicular to the target direction: driving without progress
    zigzag = np.column_stack([np.zeros(21), 0.1 * (np.arange(21) % 2)])
    wander = progress_measures([robot(zigzag, target=(0.0, -100.0))])
    assert wander["driven_per_step"] == pytest.approx(0.1)
    assert abs(wander["efficiency"]) < 0.01
    assert wander["per_step_target_visible"] is None


# ------------------------------------------------------------------------------------------- actions


def test_command_statistics_known_answers():
    actions = np.array([[1.0, -1.0], [1.0, 1.0], [0.5, 0.0], [0.5, 0.2]])
    stats = command_statistics(actions, bins=4)
    assert stats["n"] == 4
    assert stats["angular"]["mean_abs"] == pytest.approx(0.55)
    assert stats["angular"]["large_fraction"] == 0.5
    assert stats["angular"]["std"] == pytest.approx(np.std([-1.0, 1.0, 0.0, 0.2]))
    assert stats["angular"]["histogram"] == [0.25, 0.0, 0.5, 0.25]
    assert stats["linear"]["mean"] == pytest.approx(0.75)
    # angular changes -1 -> 1 -> 0 -> 0.2: two of the three steps change by more than 0.3
    assert stats["angular"]["change_fraction"] == pytest.approx(2 / 3)
    # a second sequence starting at the third action: the 1 -> 0 pair is not a step of either
    split = command_statistics(actions, bins=4, starts=np.array([True, False, True, False]))
    assert split["angular"]["change_fraction"] == pytest.approx(1 / 2)
    # main direction: one sequence turns -1, 1, 0, 0.2 (0.2 of 2.2 net: (1 + 0.2 / 2.2) / 2); split, the
    # first turns -1, 1 (balanced: 0.5) and the second 0, 0.2 (one way: 1)
    assert stats["angular"]["main_direction_share"] == pytest.approx((1 + 0.2 / 2.2) / 2)
    assert split["angular"]["main_direction_share"] == pytest.approx(0.75)


def test_main_direction_share_skips_sequences_that_never_turn():
    angular = np.array([0.5, 0.5, -0.5, 0.0, 0.0, -1.0, -1.0])
    starts = np.array([True, False, False, True, False, True, False])
    # (1 + 0.5 / 1.5) / 2 and 1; the sequence of zeros counts in neither
    assert main_direction_share(angular, starts) == pytest.approx(((2 / 3) + 1) / 2)
    assert main_direction_share(np.zeros(3), np.array([True, False, False])) is None
    assert main_direction_share(np.zeros(0), np.zeros(0, dtype=bool)) is None


def test_phase_measures_split_turns_by_time_and_by_touching():
    # pinned_at_wall: steps 0-39 free turning 0.4, steps 40-99 in contact with no turn (step 40 is taken
    # free: the contact it ends in starts there)
    phases = phase_measures([pinned_at_wall()], starts=(0, 25, 50, 200))
    assert [(p["first_step"], p["last_step"], p["robot_steps"]) for p in phases] == [
        (0, 24, 25), (25, 49, 25), (50, 199, 50), (200, None, 0)
    ]  # fmt: skip
    assert phases[0]["contact_fraction"] == 0.0 and phases[0]["touching_median_abs_turn"] is None
    assert phases[0]["free_median_abs_turn"] == pytest.approx(0.4) and phases[0]["free_large_fraction"] == 0.0
    assert phases[1]["contact_fraction"] == pytest.approx(10 / 25)  # steps 40-49
    assert phases[1]["free_median_abs_turn"] == pytest.approx(0.4)  # steps 25-40 free
    assert phases[1]["touching_median_abs_turn"] == 0.0
    assert phases[2]["contact_fraction"] == 1.0 and phases[2]["free_median_abs_turn"] is None
    assert phases[3]["contact_fraction"] is None and phases[3]["touching_median_abs_turn"] is None


def test_turn_agreement_reports_the_averaged_turns():
    expert = np.array([1.0, -1.0, 0.8, 0.1])
    predicted = np.array([0.5, 0.3, 0.2, -0.1])  # halved, wrong way, shrunk; the small turn is not counted
    out = turn_agreement(predicted, expert, threshold=0.5)
    assert out["large_turns"] == 3
    assert out["mean_abs_expert"] == pytest.approx(2.8 / 3)
    assert out["magnitude_ratio"] == pytest.approx(1.0 / 2.8)
    assert out["sign_agreement"] == pytest.approx(2 / 3)
    assert out["mse"] == pytest.approx(np.mean((predicted - expert) ** 2))
    with pytest.raises(ValueError, match="differ in shape"):
        turn_agreement(predicted[:2], expert)


# ---------------------------------------------------------------------------------------- visibility


TARGET = (5.5, 2.0)
WALL = [3.5, 4.95, 0.05, 2.05]  # x = 3.5, y in [2.9, 7.0]
FACING_TARGET_FROM_ABOVE = np.array([1.5, 6.0, math.atan2(2.0 - 6.0, 5.5 - 1.5)])


def geometry(walls) -> EpisodeGeometry:
    """One Jackal at (1.5, 2) facing +x in a 7.5 m world with ``walls``; its box target at :data:`TARGET`."""
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.world import TargetSpec, world_from_layout

    target = TargetSpec(position=np.array(TARGET, np.float32), shape="box", color="red")
    return EpisodeGeometry(world_from_layout(7.5, walls, [target], [[1.5, 2.0, 0.0]]), [JACKAL])


@pytest.fixture(scope="module")
def walled():
    return geometry([WALL])


def test_a_target_straight_ahead_in_the_open_is_visible(walled):
    assert walled.visible(0, np.array([1.5, 2.0, 0.0]))
    assert walled.visible(0, np.array([1.5, 2.0, math.radians(40)]))  # within the 45 degree half-fov
    assert geometry(np.zeros((0, 4))).visible(0, FACING_TARGET_FROM_ABOVE)


def test_a_target_behind_a_wall_or_outside_the_fov_is_not_visible(walled):
    assert not walled.visible(0, FACING_TARGET_FROM_ABOVE)  # the line of sight crosses the wall at y = 4
    assert not walled.visible(0, np.array([1.5, 2.0, math.pi]))  # facing away
    assert not walled.visible(0, np.array([1.5, 2.0, math.radians(50)]))  # just outside the fov


def test_geodesic_goes_to_the_target_and_around_the_wall(walled):
    # to the free cell nearest the solid target: 4 m less the box's half side and the robot's radius
    assert walled.geodesic(0, np.array([1.5, 2.0])) == pytest.approx(4.0 - 0.2 - 0.3, abs=0.05)
    open_world = geometry(np.zeros((0, 4)))
    assert (
        walled.geodesic(0, FACING_TARGET_FROM_ABOVE[:2])
        > open_world.geodesic(0, FACING_TARGET_FROM_ABOVE[:2]) + 0.2
    )


# ---------------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def one_episode(tmp_path_factory):
    """One smoke-setup trial (7.5 m, 2 Jackals) of 10 steps, and its file."""
    from navformer_rl.evaluation.episodes import make_episode_set, save_episode_set

    from .conftest import TINY_SETUP

    episodes = make_episode_set(
        [TINY_SETUP], trials_per_setup=1, trials_per_world=1, seed=1, name="one", max_steps=10
    )
    path = save_episode_set(episodes, tmp_path_factory.mktemp("episodes") / "one.json")
    return episodes, path


@pytest.fixture(scope="module")
def vrw_diagnosis(tmp_path_factory, one_episode):
    """VRW (seed 3) diagnosed on :func:`one_episode`: ``(out_dir, summary)``."""
    from navformer_rl.evaluation.diagnose import diagnose

    out = tmp_path_factory.mktemp("diagnose") / "vrw"
    return out, diagnose("vrw", one_episode[0], out, seed=3, progress=False)


def test_the_traces_agree_with_the_evaluation_of_the_same_episode(tmp_path, one_episode, vrw_diagnosis):
    from navformer_rl.evaluation.harness import evaluate

    episodes, _ = one_episode
    out, summary = vrw_diagnosis
    (path,) = sorted((out / "traces").glob("*.npz"))
    trace = load_trace(path)
    assert trace.steps == 10 and trace.n_robots == 2
    result = evaluate(
        "vrw", episodes, tmp_path / "eval", seed=3, maps_per_setup=0, videos_per_setup=0, progress=False
    )
    for i, row in enumerate(result.records):  # same robots, same seed: the same motion
        r = trace.robot(i)
        assert r.n == row.steps and r.success == row.success
        assert int(r.contact.sum()) == row.collisions
        assert float(r.driven.sum()) == pytest.approx(row.path_length, abs=1e-5)
        assert r.distance[-1] == pytest.approx(row.final_distance, abs=1e-5)
    # the geodesic from the start is the episode's ℓ (the same graph, searched from the other end)
    assert trace.geodesic[0] == pytest.approx(episodes.episodes[0].shortest_paths, rel=1e-5)
    targets = np.array([t["position"] for t in episodes.episodes[0].targets])
    assert trace.distance == pytest.approx(
        np.hypot(*(trace.pose[:, :, :2] - targets).transpose(2, 0, 1)), abs=1e-5
    )
    assert summary["all"]["robot_trials"] == 2 and summary["all"]["active_steps"] == sum(
        r.steps for r in result.records
    )
    written = json.loads((out / "diagnosis.json").read_text())
    assert written["all"] == json.loads(json.dumps(summary["all"]))
    assert "| measure | vrw |" in (out / "diagnosis.md").read_text()
    rows = [json.loads(line) for line in (out / "robot_trials.jsonl").read_text().splitlines()]
    assert [(row["robot"], row["steps"]) for row in rows] == [
        (i, row.steps) for i, row in enumerate(result.records)
    ]
    assert sum(summary["all"]["outcomes"].values()) == pytest.approx(1.0)


def test_a_rerun_reuses_the_traces_and_fresh_recomputes_them(vrw_diagnosis, one_episode):
    from navformer_rl.evaluation.diagnose import diagnose

    out, first = vrw_diagnosis
    again = diagnose("vrw", one_episode[0], out, seed=3, progress=False)
    assert again["episodes_computed"] == 0 and again["all"] == first["all"]
    other_seed = diagnose("vrw", one_episode[0], out, seed=4, progress=False)
    assert other_seed["episodes_computed"] == 1  # another seed is other work


def test_a_shorter_context_is_recorded_and_is_other_work(tmp_path, one_episode):
    from navformer_rl.evaluation.diagnose import diagnose
    from navformer_rl.modules import NavFormerConfig

    from .conftest import make_checkpoint

    checkpoint = make_checkpoint(tmp_path / "navformer", NavFormerConfig())
    out = tmp_path / "diagnosis"
    whole = diagnose("navformer", one_episode[0], out, checkpoint=checkpoint, progress=False)
    short = diagnose("navformer", one_episode[0], out, checkpoint=checkpoint, context_steps=2, progress=False)
    assert (whole["context_steps"], short["context_steps"]) == (None, 2)
    assert short["episodes_computed"] == 1  # the whole context's trace is not reused
    assert json.loads((out / "diagnosis.json").read_text())["context_steps"] == 2


def test_a_trace_survives_saving_and_a_damaged_file_is_refused(tmp_path, vrw_diagnosis):
    out, _ = vrw_diagnosis
    (path,) = sorted((out / "traces").glob("*.npz"))
    trace = load_trace(path)
    copy = save_trace(trace, tmp_path / "copy.npz")
    again = load_trace(copy)
    for name in ("pose", "action", "velocity", "contact", "geodesic", "visible", "success_step"):
        np.testing.assert_array_equal(getattr(again, name), getattr(trace, name))
    assert again.key == trace.key and again.robots == trace.robots
    copy.write_bytes(copy.read_bytes()[:100])
    with pytest.raises(ValueError, match="not a diagnosis trace"):
        load_trace(copy)


def test_the_cli_diagnoses_and_compares_with_another_folder(tmp_path, one_episode, vrw_diagnosis, capsys):
    from navformer_rl.cli import main

    _, path = one_episode
    out = tmp_path / "fca"
    code = main(["evaluate", "diagnose", "--method", "fca", "--episodes", str(path), "--out", str(out),
                 "--compare", str(vrw_diagnosis[0]), "--no-progress"])  # fmt: skip
    assert code == 0
    table = (out / "diagnosis.md").read_text()
    assert "| measure | fca | vrw |" in table
    assert str(out / "diagnosis.md") in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--method", "vrw", "--held-out", "E", "CA"], "held-out.* does not exist"),
        (["--method", "navformer"], "needs a checkpoint"),
        (
            ["--method", "vrw", "--context-steps", "3"],
            r"context_steps=3 \(--context-steps\) applies to navformer",
        ),
    ],
)
def test_the_cli_refuses_bad_requests_in_one_line(tmp_path, one_episode, capsys, extra, message):
    from navformer_rl.cli import main

    _, path = one_episode
    assert main(["evaluate", "diagnose", "--episodes", str(path), "--out", str(tmp_path / "d"), *extra]) == 2
    assert re_search(message, capsys.readouterr().err)


def test_the_cli_refuses_an_unknown_method(tmp_path, one_episode, capsys):
    from navformer_rl.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(
            [
                "evaluate",
                "diagnose",
                "--method",
                "walk",
                "--episodes",
                str(one_episode[1]),
                "--out",
                str(tmp_path),
            ]
        )
    assert exit_info.value.code == 2 and "invalid choice: 'walk'" in capsys.readouterr().err


def re_search(pattern: str, text: str) -> bool:
    import re

    return re.search(pattern, text) is not None


# ------------------------------------------------------------------------------ a model's own actions

TINY_MODEL = {"d_embed": 16, "d_head": 8, "n_blocks": 1, "max_timestep": 64}


@pytest.fixture(scope="module")
def expert_sets(tmp_path_factory):
    from navformer_rl.data import make_synthetic_dataset

    root = tmp_path_factory.mktemp("experts")
    return {
        "e": make_synthetic_dataset(root / "e", "e", 4, 5, 12, seed=11),
        "ca": make_synthetic_dataset(root / "ca", "ca", 4, 3, 8, seed=12),
    }


def test_teacher_forced_turns_score_the_windows_navformer_validate_scores(
    tmp_path, expert_sets, checkpoint_factory
):
    from navformer_rl.evaluation.diagnose.actions import teacher_forced_turns
    from navformer_rl.modules import NavFormerConfig
    from navformer_rl.training.validation import score_checkpoints

    run = checkpoint_factory(tmp_path / "run", NavFormerConfig(**TINY_MODEL))
    turns = teacher_forced_turns(str(run), expert_sets, batch_trajs=3)
    (scores,) = score_checkpoints([str(run)], {k: str(v) for k, v in expert_sets.items()})
    assert turns["e"]["loss_dt"] == pytest.approx(scores["loss_dt_exploration"], rel=1e-5)
    assert turns["ca"]["loss_dt"] == pytest.approx(scores["loss_dt_collision_avoidance"], rel=1e-5)


def test_a_navformer_diagnosis_sets_its_turns_beside_the_experts(
    tmp_path, one_episode, expert_sets, checkpoint_factory
):
    from navformer_rl.cli import main
    from navformer_rl.modules import NavFormerConfig

    run = checkpoint_factory(tmp_path / "run", NavFormerConfig(**TINY_MODEL))
    out = tmp_path / "nf"
    sets = [str(expert_sets["e"]), str(expert_sets["ca"])]
    code = main(["evaluate", "diagnose", "--method", "navformer", "--checkpoint", str(run), "--episodes",
                 str(one_episode[1]), "--out", str(out), "--expert-data", *sets, "--held-out", *sets,
                 "--no-progress"])  # fmt: skip
    assert code == 0
    summary = json.loads((out / "diagnosis.json").read_text())
    assert set(summary["teacher_forced"]) == set(summary["expert_commands"]) == {"e", "ca"}
    table = (out / "diagnosis.md").read_text()
    assert "| navformer, D_e |" in table and "| std |" in table
