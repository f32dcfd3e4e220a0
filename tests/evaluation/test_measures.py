"""SR / SPL / CR and their intervals on hand-computed cases."""

import dataclasses

import numpy as np
import pytest

from navformer_rl.evaluation.measures import (
    RobotTrial,
    TrialTracker,
    bootstrap_mean_interval,
    check_cluster,
    clustered_wilson_interval,
    collision_rate,
    collision_rate_terms,
    min_trials_for_interval,
    spl,
    spl_terms,
    success_rate,
    summarize,
    wilson_interval,
)


def test_spl_by_hand_caps_and_failures():
    # success l=4 p=5 -> 0.8; success with p < l (stopped in the 1.5 m disc) -> capped at 1;
    # failure -> 0 whatever it drove.  Mean = (0.8 + 1 + 0) / 3 = 0.6.
    success = np.array([True, True, False])
    shortest = np.array([4.0, 3.0, 5.0])
    driven = np.array([5.0, 2.0, 1.0])
    np.testing.assert_allclose(spl_terms(success, shortest, driven), [0.8, 1.0, 0.0])
    assert spl(success, shortest, driven) == pytest.approx(0.6)


def test_two_trial_spl():
    # Two successes: 6/8 and 10/20 -> (0.75 + 0.5) / 2 = 0.625.
    assert spl(np.array([1, 1], bool), np.array([6.0, 10.0]), np.array([8.0, 20.0])) == pytest.approx(0.625)


def test_spl_rejects_bad_lengths():
    with pytest.raises(ValueError, match="shortest"):
        spl(np.array([True]), np.array([0.0]), np.array([1.0]))
    with pytest.raises(ValueError, match="shortest"):
        spl(np.array([True]), np.array([np.inf]), np.array([1.0]))
    with pytest.raises(ValueError, match="same length"):
        spl(np.array([True, False]), np.array([1.0]), np.array([1.0]))


def test_collision_rate_is_per_trial_then_mean():
    # 10 collisions in 50 steps (0.2) and 0 in 500 (0.0): mean 0.1, not the pooled 10/550.
    collisions = np.array([10, 0])
    steps = np.array([50, 500])
    np.testing.assert_allclose(collision_rate_terms(collisions, steps), [0.2, 0.0])
    assert collision_rate(collisions, steps) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="collision counts"):
        collision_rate(np.array([3]), np.array([2]))


def test_success_rate():
    assert success_rate(np.array([True, False, False, True])) == 0.5


def test_wilson_known_values():
    # 0/10: upper = (z^2/n) / (1 + z^2/n) = 0.27754 with z = 1.95996.
    low, high = wilson_interval(0, 10)
    assert low == pytest.approx(0.0, abs=1e-12)
    assert high == pytest.approx(0.277535, abs=1e-5)
    # 47/120 (paper Table I, VRW 7.5 m / 2 robots = 39.17 %), by hand: (0.30899, 0.48106).
    low, high = wilson_interval(47, 120)
    assert low == pytest.approx(0.30899, abs=1e-4)
    assert high == pytest.approx(0.48106, abs=1e-4)
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(3, 2)


def test_bootstrap_is_seeded_and_brackets_the_mean():
    # six trials: the fewest a 95 % trial-level bootstrap accepts (three used to be enough)
    values = np.array([0.0, 0.2, 0.4, 1.0, 0.9, 0.1, 0.5, 0.5, 0.3, 0.7, 0.8, 0.6])
    groups = np.repeat(np.arange(6), 2)
    a = bootstrap_mean_interval(values, groups, seed=3)
    b = bootstrap_mean_interval(values, groups, seed=3)
    assert a == b
    assert a[0] <= values.mean() <= a[1]
    # Constant values: a degenerate interval.
    assert bootstrap_mean_interval(np.full(6, 0.25)) == (0.25, 0.25)


def test_min_trials_for_interval():
    # smallest G with 1 - 2^(1 - G) >= confidence: the range of G trial means misses the true mean with
    # probability >= 2^(1 - G), and a percentile bootstrap never leaves that range
    assert min_trials_for_interval() == min_trials_for_interval(0.95) == 6  # 1 - 1/32 = 0.969; 5: 0.9375
    assert min_trials_for_interval(0.90) == 5  # 1 - 1/16 = 0.9375; 4: 0.875
    assert min_trials_for_interval(0.99) == 8  # 1 - 1/128 = 0.992; 7: 0.984
    assert min_trials_for_interval(0.75) == 3  # exactly 1 - 1/4
    with pytest.raises(ValueError, match="confidence"):
        min_trials_for_interval(1.0)


def test_bootstrap_with_too_few_trials_gives_no_interval():
    # one trial: nothing to resample, the interval used to be (0.5, 0.5); two identical trials likewise;
    # five trials: a 95 % percentile interval could cover at most 1 - 2^-4 = 93.75 % of the time
    values = np.array([0.0, 1.0, 0.5, 0.5])
    for groups in (np.zeros(4, int), np.array([0, 0, 1, 1])):
        low, high = bootstrap_mean_interval(values, groups)
        assert np.isnan(low) and np.isnan(high)
    assert np.isnan(bootstrap_mean_interval(np.arange(5.0), np.arange(5))).all()
    assert np.isfinite(bootstrap_mean_interval(np.arange(6.0), np.arange(6))).all()
    # at 90 % five trials are enough (1 - 2^-4 = 93.75 % >= 90 %)
    assert np.isfinite(bootstrap_mean_interval(np.arange(5.0), np.arange(5), confidence=0.9)).all()


def _trial(episode, robot, success, steps, collisions, p, shortest):
    return RobotTrial(
        method="m",
        episode_id=episode,
        setup="s",
        size=7.5,
        n_robots=2,
        world_seed=0,
        trial=0,
        robot=robot,
        robot_style="jackal",
        measured=True,
        success=success,
        success_step=steps if success else None,
        steps=steps,
        collisions=collisions,
        path_length=p,
        shortest_path=shortest,
        shortest_path_to_disc=max(shortest - 1.5, 0.1),
        final_distance=1.0 if success else 4.0,
    )


def test_clustered_wilson_known_cases():
    # one robot per trial: the plain Wilson interval
    success = np.array([1, 0, 1, 1, 0, 1, 1, 0], dtype=bool)
    assert clustered_wilson_interval(success, np.arange(8)) == pytest.approx(wilson_interval(5, 8))
    # ... with fewer trials than an estimate of deff needs too (n_eff = trials = robots)
    assert clustered_wilson_interval(success[:3], np.arange(3)) == pytest.approx(wilson_interval(2, 3))
    # robots of a trial always agree: the Wilson interval over trials (5 of 8 trials, 3 robots each)
    assert clustered_wilson_interval(np.repeat(success, 3), np.repeat(np.arange(8), 3)) == pytest.approx(
        wilson_interval(5, 8)
    )
    # all equal: n_eff = number of trials
    assert clustered_wilson_interval(np.zeros(6, dtype=bool), np.repeat([0, 1, 2], 2)) == pytest.approx(
        wilson_interval(0, 3)
    )
    # hand-computed design effect below 1, clamped (never narrower than independent robots): five trials of
    # four with {2, 1, 2, 1, 2} successes; p = 8/20, p m = 1.6, var_c = (3 * 0.4^2 + 2 * 0.6^2) / 400 =
    # 1.2 / 400 = 0.003; binomial p(1-p)/N = 0.24 / 20 = 0.012 -> deff = 0.25 -> n_eff = N = 20.
    # Six trials: the fewest from which deff is estimated at 95 %; the sixth trial also has 2 of 4.
    counts = [2, 1, 2, 1, 2, 2]
    mixed = np.concatenate([np.arange(4) < k for k in counts])
    assert clustered_wilson_interval(mixed, np.repeat(np.arange(6), 4)) == pytest.approx(
        wilson_interval(10, 24)
    )
    # six trials of two {1,1}, {1,1}, {0,0}, {1,0}, {0,0}, {1,1}: p = 7/12, p m = 7/6; deviations
    # 5/6, 5/6, -7/6, -1/6, -7/6, 5/6 -> sum of squares (3 * 25 + 2 * 49 + 1) / 36 = 174 / 36;
    # var_c = (174 / 36) / 144; binomial (7/12)(5/12) / 12 = (35 / 144) / 12 -> deff = (174 / 36) * 12 / 35
    # = 1.6571 -> n_eff = 12 / 1.6571 = 7.2414
    grouped = np.array([1, 1, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1], dtype=bool)
    n_eff = 12 / ((174 / 36) * 12 / 35)
    assert n_eff == pytest.approx(7.2414, abs=1e-4)
    assert clustered_wilson_interval(grouped, np.repeat(np.arange(6), 2)) == pytest.approx(
        wilson_interval(7 / 12 * n_eff, n_eff)
    )
    with pytest.raises(ValueError, match="matching"):
        clustered_wilson_interval(success, np.arange(3))


def test_clustered_wilson_with_too_few_trials_counts_trials():
    # One trial, 3 of 6 robots: the between-trial variance computes as 0 whatever the outcomes, so deff used
    # to be clamped to 1 and the 6 robots counted as independent: wilson_interval(3, 6) = [18.8, 81.2] %,
    # while 0 of 6 in the same trial gave n_eff = 1 trial. Now both use n_eff = 1 trial.
    # Wilson at n = 1, p = 0.5, z = 1.959964: centre 0.5, half = z sqrt(0.25 + z^2 / 4) / (1 + z^2)
    # = 1.959964 * 1.100166 / 4.841459 = 0.445379 -> [0.054621, 0.945379].
    half = 1.959964 * np.sqrt(0.25 + 1.959964**2 / 4) / (1 + 1.959964**2)
    one = np.array([1, 1, 1, 0, 0, 0], dtype=bool)
    assert clustered_wilson_interval(one, np.zeros(6, int)) == pytest.approx(
        (0.5 - half, 0.5 + half), abs=1e-6
    )
    assert clustered_wilson_interval(one, np.zeros(6, int)) == pytest.approx((0.054621, 0.945379), abs=1e-6)
    assert wilson_interval(3, 6) == pytest.approx((0.187616, 0.812384), abs=1e-6)  # the old, too narrow
    assert clustered_wilson_interval(np.zeros(6, bool), np.zeros(6, int)) == pytest.approx(
        wilson_interval(0, 1)
    )
    # Two identical trials {1,1,0,0}: var_c = 0 again (by chance, from one degree of freedom) -> used to be
    # wilson_interval(4, 8) = [21.5, 78.5] %; now n_eff = 2 trials: n = 2, p = 0.5, centre 0.5,
    # half = z sqrt(0.125 + z^2 / 16) / (1 + z^2 / 2) = 1.959964 * 0.604228 / 2.920729 = 0.405469.
    two = np.array([1, 1, 0, 0, 1, 1, 0, 0], dtype=bool)
    groups = np.repeat([0, 1], 4)
    half = 1.959964 * np.sqrt(0.125 + 1.959964**2 / 16) / (1 + 1.959964**2 / 2)
    assert clustered_wilson_interval(two, groups) == pytest.approx((0.5 - half, 0.5 + half), abs=1e-6)
    assert clustered_wilson_interval(two, groups) == pytest.approx((0.094531, 0.905469), abs=1e-6)
    # five trials (below 6 at 95 %): still the number of trials, whatever their spread
    five = np.concatenate([np.arange(4) < k for k in [2, 1, 2, 1, 2]])
    assert clustered_wilson_interval(five, np.repeat(np.arange(5), 4)) == pytest.approx(wilson_interval(2, 5))
    # at 90 % five trials are enough to estimate deff (here clamped to 1: n_eff = 20 robots)
    assert clustered_wilson_interval(five, np.repeat(np.arange(5), 4), 0.9) == pytest.approx(
        wilson_interval(8, 20, 0.9)
    )


def test_summarize_and_record_round_trip():
    records = [
        _trial("e0", 0, True, 40, 4, 5.0, 4.0),  # spl 0.8, cr 0.1
        _trial("e0", 1, False, 500, 50, 12.0, 6.0),  # spl 0, cr 0.1
        _trial("e1", 0, True, 20, 0, 2.0, 3.0),  # spl 1, cr 0
        _trial("e1", 1, True, 100, 40, 10.0, 5.0),  # spl 0.5, cr 0.4
    ]
    s = summarize(records)
    assert s.n_robot_trials == 4 and s.n_trials == 2
    assert s.sr == pytest.approx(0.75)
    assert s.spl == pytest.approx((0.8 + 0 + 1 + 0.5) / 4)
    assert s.cr == pytest.approx((0.1 + 0.1 + 0 + 0.4) / 4)
    # two trials, too few to estimate the design effect (it used to be clamped to 1: wilson_interval(3, 4)):
    # n_eff = 2 trials, and too few for a trial-level bootstrap of SPL / CR
    assert s.sr_ci == pytest.approx(wilson_interval(1.5, 2))
    for ci in (s.spl_ci, s.cr_ci, s.spl_disc_ci):
        assert np.isnan(ci).all()
    # SPL-disc uses l - 1.5 here: 2.5/5, 0, 1.5/max(2, 1.5), 3.5/10.
    assert s.spl_disc == pytest.approx((0.5 + 0 + 0.75 + 0.35) / 4)
    row = records[0].to_dict()
    assert row["spl"] == pytest.approx(0.8) and row["collision_rate"] == pytest.approx(0.1)
    assert RobotTrial.from_dict(row) == records[0]


def _maze_protocol_records():
    """6 mazes x 3 trials x 2 robots of one setup, where the maze decides: every robot succeeds in the even
    mazes and fails in the odd ones (SPL 0.8 / 0), and robot 1 of each trial collides in 1 of 10 steps."""
    records = []
    for world in range(6):
        for trial in range(3):
            for robot in range(2):
                win = world % 2 == 0
                record = _trial(f"w{world}t{trial}", robot, win, 10, robot, 5.0 if win else 9.0, 4.0)
                records.append(dataclasses.replace(record, world_seed=100 + world, trial=trial))
    return records


def test_intervals_cluster_by_trial_or_by_maze():
    records = _maze_protocol_records()
    by_trial, by_maze = summarize(records), summarize(records, cluster="world")
    assert (by_trial.n_trials, by_trial.n_worlds, by_trial.cluster) == (18, 6, "trial")
    assert (by_maze.n_trials, by_maze.n_worlds, by_maze.cluster) == (18, 6, "world")
    assert by_maze.sr == by_trial.sr == 0.5 and by_maze.spl == by_trial.spl == pytest.approx(0.4)
    success = np.array([r.success for r in records])
    trials = np.repeat(np.arange(18), 2)
    mazes = np.repeat(np.arange(6), 6)
    # robots of a maze always agree: n_eff = the number of trials, or of mazes
    assert by_trial.sr_ci == pytest.approx(wilson_interval(9, 18))
    assert by_maze.sr_ci == pytest.approx(wilson_interval(3, 6))
    assert by_maze.sr_ci == pytest.approx(clustered_wilson_interval(success, mazes))
    assert by_trial.sr_ci == pytest.approx(clustered_wilson_interval(success, trials))
    spl_values = np.array([r.spl for r in records])
    assert by_maze.spl_ci == pytest.approx(bootstrap_mean_interval(spl_values, mazes, seed=0))
    # the maze decides the outcome, so resampling mazes (6 units) gives the wider interval
    assert by_maze.sr_ci[1] - by_maze.sr_ci[0] > by_trial.sr_ci[1] - by_trial.sr_ci[0]
    assert by_maze.spl_ci[1] - by_maze.spl_ci[0] >= by_trial.spl_ci[1] - by_trial.spl_ci[0]
    # CR: robot 1 always 0.1, robot 0 always 0 -> every trial and maze has mean 0.05: a zero-width interval
    assert by_maze.cr_ci == pytest.approx((0.05, 0.05))


def test_maze_clusters_need_enough_mazes_and_are_told_apart_by_setup():
    records = _maze_protocol_records()
    five = [r for r in records if r.world_seed != 105]  # 5 mazes, 15 trials
    by_maze = summarize(five, cluster="world")
    assert by_maze.n_worlds == 5 and np.isnan(by_maze.spl_ci).all() and np.isnan(by_maze.cr_ci).all()
    assert by_maze.sr_ci == pytest.approx(wilson_interval(3, 5))  # 3 of 5 mazes succeed, n_eff = 5
    assert not np.isnan(summarize(five).spl_ci).any()  # 15 trials are enough for trial clusters
    # the same world seed in another setup is another maze
    other_setup = [dataclasses.replace(r, setup="s2", episode_id="s2-" + r.episode_id) for r in five[:6]]
    assert summarize(five + other_setup, cluster="world").n_worlds == 6


def test_unknown_cluster_level_is_refused():
    assert check_cluster("world") == "world"
    with pytest.raises(ValueError, match="cluster='maze': expected one of trial, world"):
        summarize(_maze_protocol_records(), cluster="maze")


def test_trial_tracker_counts_only_active_steps():
    tracker = TrialTracker(np.array([[0.0, 0.0], [5.0, 5.0]]))
    # step 1: robot 0 moves 1 m and collides; robot 1 moves 0.5 m.
    tracker.update(np.array([[1.0, 0.0], [5.0, 5.5]]), np.array([True, False]), np.array([False, False]))
    # step 2: robot 0 moves (3,4) -> 5 m and succeeds; robot 1 collides, no motion.
    tracker.update(np.array([[4.0, 4.0], [5.0, 5.5]]), np.array([False, True]), np.array([True, False]))
    # step 3: robot 0 is done (motion and contact ignored); robot 1 moves 1 m.
    tracker.update(np.array([[9.0, 9.0], [6.0, 5.5]]), np.array([True, False]), np.array([True, False]))
    np.testing.assert_allclose(tracker.path_length, [6.0, 1.5])
    np.testing.assert_array_equal(tracker.steps, [2, 3])
    np.testing.assert_array_equal(tracker.collisions, [1, 1])
    np.testing.assert_array_equal(tracker.success, [True, False])
    np.testing.assert_array_equal(tracker.success_step, [2, -1])


def test_trial_tracker_refuses_bad_input_without_counting_it():
    tracker = TrialTracker(np.array([[0.0, 0.0]]))
    for xy, driven in (([[1.0, 0.0]], [-1.0]), ([[1.0, 0.0]], [np.nan]), ([[np.nan, 0.0]], None)):
        with pytest.raises(ValueError, match="finite"):
            tracker.update(np.array(xy), np.array([True]), np.array([False]), driven=driven)
    np.testing.assert_array_equal(tracker.steps, [0])
    np.testing.assert_array_equal(tracker.collisions, [0])
    tracker.update(np.array([[1.0, 0.0]]), np.array([True]), np.array([False]))
    np.testing.assert_array_equal(tracker.steps, [1])
    np.testing.assert_allclose(tracker.path_length, [1.0])


def test_trial_tracker_takes_given_step_lengths():
    # Arc lengths per step (e.g. |v| dt) instead of chords: a quarter circle of radius 1 driven in one step.
    tracker = TrialTracker(np.array([[0.0, 0.0]]))
    tracker.update(np.array([[1.0, 1.0]]), np.array([False]), np.array([False]), driven=np.array([np.pi / 2]))
    np.testing.assert_allclose(tracker.path_length, [np.pi / 2])
    with pytest.raises(ValueError, match="driven"):
        tracker.update(np.array([[1.0, 1.0]]), np.array([False]), np.array([False]), driven=np.array([-1.0]))


def test_all_equal_outcomes_give_exact_interval_ends_and_a_plot(tmp_path):
    # SR = 1 over the paper's 60 trials (2 robots): rounding used to leave the Wilson upper end at
    # 1 - 2e-16, a negative error bar that matplotlib refuses after every episode had run
    for n in (5, 10, 17, 20, 60, 120):
        assert wilson_interval(n, n)[1] == 1.0
        assert wilson_interval(0, n)[0] == 0.0
    records = [_trial(f"e{i}", robot, True, 50, 0, 5.0, 5.0) for i in range(60) for robot in range(2)]
    s = summarize(records)
    assert s.sr == 1.0 and s.sr_ci[1] == 1.0
    assert s.spl_ci == (1.0, 1.0) and s.cr_ci == (0.0, 0.0)
    from navformer_rl.evaluation.plots import plot_setup_bars
    from navformer_rl.evaluation.tables import summarize_by_setup

    failures = [
        dataclasses.replace(_trial(f"e{i}", robot, False, 500, 0, 5.0, 5.0), method="never")
        for i in range(60)
        for robot in range(2)
    ]
    path = plot_setup_bars(summarize_by_setup(records + failures), tmp_path / "bars.png")
    assert path.stat().st_size > 0
