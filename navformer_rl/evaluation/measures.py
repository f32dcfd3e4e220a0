"""The paper's navigation measures (§VII.A): SR, SPL (eq. 12) and CR, per robot-trial and aggregated.

A *robot-trial* is one robot in one trial (episode); a trial with ``R`` robots gives ``R`` robot-trials and
``N_tau`` below counts robot-trials, as in the paper. Everything here is pure numpy.

Definitions (``i`` runs over the ``N_tau`` robot-trials):

- **SR** = ``(1 / N_tau) * sum_i S_i`` with ``S_i`` = 1 if robot ``i`` came within
  :data:`~navformer_rl.constants.SUCCESS_RADIUS` (1.5 m) of its target before the trial ended.
- **SPL** (eq. 12, Anderson et al. 2018) = ``(1 / N_tau) * sum_i S_i * l_i / max(p_i, l_i)`` with
  ``l_i`` the shortest collision-free path length on the true map from the robot's start to its target
  position (a grid path with straight moves of up to 5 cells, within 0.49 % of the straight line in free
  space, on the map inflated by the robot radius:
  :data:`navformer_rl.evaluation.episodes.SHORTEST_PATH_REACH`,
  :meth:`navformer_rl.envs.occupancy.OccupancyMap.shortest_path_length`) and ``p_i`` the path the robot
  actually drove over the steps it was active: the harness sums the arc length ``|v_t| * dt`` of each executed
  unicycle step (the env's own ``path_length`` counter); :class:`TrialTracker` falls back to the straight-line
  displacement ``||xy_t - xy_{t-1}||`` of the real pose when no step lengths are given. Failed robot-trials
  contribute 0; a successful robot that stopped inside the 1.5 m disc with ``p_i < l_i`` contributes exactly 1
  (the ``max`` caps the ratio).
- **CR** = ``(1 / N_tau) * sum_i N_c,i / N_e,i`` with ``N_c,i`` the number of steps on which robot ``i``
  was in contact (wall, target or robot: its motion was cut short, or after the step its disc is within
  :data:`~navformer_rl.envs.sim.CONTACT_EPS` = 1 mm of one, so a robot that is driven into counts too) and
  ``N_e,i`` the number of steps robot ``i`` was active: from the reset up to and including the step it
  succeeded, or to the end of the trial if it never did. A ratio is taken per robot-trial first, then
  averaged (not pooled).

Secondary measure: **SPL-disc**, eq. 12 with ``l_i`` replaced by the shortest path to the 1.5 m success
disc around the target (``RobotTrial.shortest_path_to_disc``); it does not give the 1.5 m of slack that
``l_i`` to the target gives a robot that stops at the disc's edge. Reported in ``summary.csv`` and the
report, not in the Table I-layout ``summary.md``.

Confidence intervals (95 % by default). The robots of one trial share a world and each other's company, so
they are not independent: for SR, a Wilson score interval on Kish's effective sample size
``n / deff`` (``clustered_wilson_interval``: the design effect ``deff`` compares the trial-clustered
variance of SR with the binomial one, never below 1); for SPL and CR, a percentile bootstrap that resamples
whole trials, seeded so that the same records always give the same interval. Both read the spread between
trials, which a few trials cannot show: below :func:`min_trials_for_interval` trials (6 at 95 %) SR's
effective sample size is the number of trials (each trial one observation of the proportion, the
conservative end) and SPL / CR get no interval (``(nan, nan)``, written ``n/a`` in the tables).

What counts as a cluster (:data:`CLUSTER_LEVELS`, ``summarize(..., cluster=...)``): ``"trial"`` (the
default) treats the trials as the independent units, so the intervals describe the method on the mazes
that were drawn (every method of a comparison faces the same ones); ``"world"`` treats the mazes as the
units (the paper's protocol draws a new maze every 10 trials, and trials in one maze share its
difficulty), so the intervals also cover the variation from maze to maze - wider, and they need
:func:`min_trials_for_interval` mazes per row (the paper's 60 trials per setup hold 6).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from statistics import NormalDist

import numpy as np


def success_rate(success: np.ndarray) -> float:
    """SR = mean of ``success`` (bool ``[N]``) over robot-trials."""
    success = _as_1d(success, "success").astype(bool)
    return float(success.mean())


def spl_terms(success: np.ndarray, shortest: np.ndarray, driven: np.ndarray) -> np.ndarray:
    """Per robot-trial SPL terms ``S_i * l_i / max(p_i, l_i)`` as float64 ``[N]`` (eq. 12).

    Args:
        success: bool ``[N]``, ``S_i``.
        shortest: float ``[N]``, ``l_i`` in metres; must be finite and > 0.
        driven: float ``[N]``, ``p_i`` in metres; must be finite and >= 0.
    """
    success = _as_1d(success, "success").astype(bool)
    shortest = _as_1d(shortest, "shortest").astype(np.float64)
    driven = _as_1d(driven, "driven").astype(np.float64)
    if not success.shape == shortest.shape == driven.shape:
        raise ValueError(
            f"success, shortest and driven must have the same length, got {success.shape}, "
            f"{shortest.shape}, {driven.shape}"
        )
    if not np.all(np.isfinite(shortest)) or np.any(shortest <= 0):
        raise ValueError(f"shortest path lengths must be finite and > 0, got {shortest[~(shortest > 0)]}")
    if not np.all(np.isfinite(driven)) or np.any(driven < 0):
        raise ValueError("driven path lengths must be finite and >= 0")
    return np.where(success, shortest / np.maximum(driven, shortest), 0.0)


def spl(success: np.ndarray, shortest: np.ndarray, driven: np.ndarray) -> float:
    """SPL (eq. 12) = mean of :func:`spl_terms` over robot-trials."""
    return float(spl_terms(success, shortest, driven).mean())


def collision_rate_terms(collisions: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Per robot-trial ``N_c,i / N_e,i`` as float64 ``[N]``; a robot-trial with ``N_e,i = 0`` gives 0.

    Args:
        collisions: int ``[N]``, steps in contact ``N_c,i`` (``0 <= N_c,i <= N_e,i``).
        steps: int ``[N]``, active steps ``N_e,i``.
    """
    collisions = _as_1d(collisions, "collisions").astype(np.int64)
    steps = _as_1d(steps, "steps").astype(np.int64)
    if collisions.shape != steps.shape:
        raise ValueError(f"collisions and steps must match, got {collisions.shape} and {steps.shape}")
    if np.any(collisions < 0) or np.any(collisions > steps):
        raise ValueError("collision counts must lie in [0, steps] for every robot-trial")
    return np.divide(collisions, steps, out=np.zeros(len(steps)), where=steps > 0)


def collision_rate(collisions: np.ndarray, steps: np.ndarray) -> float:
    """CR = mean over robot-trials of ``N_c,i / N_e,i`` (see :func:`collision_rate_terms`)."""
    return float(collision_rate_terms(collisions, steps).mean())


def wilson_interval(successes: float, n: float, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion ``successes / n`` (``n`` may be an effective size).

    ``centre = (p + z^2 / 2n) / (1 + z^2 / n)``,
    ``half = z * sqrt(p (1 - p) / n + z^2 / 4n^2) / (1 + z^2 / n)``, ``z`` the normal quantile.
    """
    if not (n > 0 and 0 <= successes <= n):
        raise ValueError(f"need 0 <= successes <= n and n > 0, got successes={successes}, n={n}")
    z = _normal_quantile(confidence)
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    # the ends are exact at p = 0 and p = 1: rounding would leave them ~1e-16 inside the estimate
    low = 0.0 if successes == 0 else max(0.0, float(centre - half))
    high = 1.0 if successes == n else min(1.0, float(centre + half))
    return low, high


def min_trials_for_interval(confidence: float = 0.95) -> int:
    """The fewest trials (groups; mazes when the intervals cluster by world) from which an interval is read
    off the spread between them: the smallest ``G`` with ``1 - 2^(1 - G) >= confidence`` (6 at 95 %, 5 at
    90 %, 8 at 99 %).

    Why: a percentile bootstrap over ``G`` trials lies within the range of the ``G`` trial means, and that
    range misses the true mean with probability ``q^G + (1 - q)^G >= 2^(1 - G)`` (``q`` the chance that one
    trial's mean lies above it; a continuous distribution): with fewer trials no trial-level bootstrap can
    reach its nominal level (5 trials: at most 93.75 %, 2: 50 %, 1: 0 %). SR's design effect is read off
    the same spread (``G - 1`` degrees of freedom), and the same threshold serves it: in a beta-binomial
    simulation (2-6 robots, intra-trial correlation 0-0.6, 95 %) the estimated design effect covered the
    true SR as little as 76 % of the time with 2 trials and 84 % with 3-4, the number of trials as the
    sample size at least 94 %.
    """
    _normal_quantile(confidence)  # refuses a confidence outside (0, 1)
    trials = 1
    while 1.0 - 2.0 ** (1 - trials) < confidence:
        trials += 1
    return trials


def clustered_wilson_interval(
    success: np.ndarray, groups: np.ndarray, confidence: float = 0.95
) -> tuple[float, float]:
    """Wilson interval of the success rate of ``success`` (bool ``[N]``) clustered by ``groups`` (``[N]``).

    Design effect ``deff = var_c / (p (1 - p) / N)`` with the cluster-robust variance of the mean
    ``var_c = sum_g (s_g - p m_g)^2 / N^2`` (``s_g`` successes and ``m_g`` members of group g); the interval
    is ``wilson_interval(p n_eff, n_eff)`` with Kish's effective size ``n_eff = N / max(deff, 1)``. One member
    per group gives the plain Wilson interval; groups whose members always agree give the Wilson interval
    over groups. ``deff`` is not estimated, and ``n_eff`` is the number of groups ``G`` (each group one
    observation of the proportion: the conservative end, exact when members always agree), when

    - every outcome is equal (p = 0 or 1): ``var_c`` and the binomial variance are both 0;
    - there are fewer than :func:`min_trials_for_interval` groups (6 at 95 %): with one group ``var_c`` is 0
      whatever the outcomes (it has no between-group spread to measure, so ``deff`` would be clamped to 1 and
      the members counted as independent), and with a few it rests on ``G - 1`` degrees of freedom, so two
      groups that happen to agree (say 2 of 4 successes in each) would also give ``deff = 1``.
    """
    success = _as_1d(success, "success").astype(np.float64)
    groups = _as_1d(groups, "groups")
    if len(success) == 0 or groups.shape != success.shape:
        raise ValueError(
            f"need matching non-empty success and groups, got {success.shape} and {groups.shape}"
        )
    _, inverse = np.unique(groups, return_inverse=True)
    n, p = len(success), float(success.mean())
    members = np.bincount(inverse).astype(np.float64)
    if p in (0.0, 1.0) or len(members) < min_trials_for_interval(confidence):
        n_eff = float(len(members))
    else:
        clustered_variance = ((np.bincount(inverse, weights=success) - p * members) ** 2).sum() / n**2
        n_eff = n / max(clustered_variance / (p * (1 - p) / n), 1.0)
    return wilson_interval(p * n_eff, n_eff, confidence)


def bootstrap_mean_interval(
    values: np.ndarray,
    groups: np.ndarray | None = None,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (float ``[N]``), or ``(nan, nan)`` when there
    are fewer than :func:`min_trials_for_interval` groups (6 at 95 %), too few for the interval to reach
    its level (one group: nothing to resample, the interval would have zero width).

    With ``groups`` (int ``[N]``, e.g. the trial of each robot-trial) whole groups are resampled with
    replacement (cluster bootstrap) and each resample's statistic is the mean over all values of the drawn
    groups; without, single values are resampled. Seeded: the same inputs give the same interval.
    """
    values = _as_1d(values, "values").astype(np.float64)
    if len(values) == 0:
        raise ValueError("cannot bootstrap an empty set of values")
    min_groups = min_trials_for_interval(confidence)
    if groups is None:
        groups = np.arange(len(values))
    groups = _as_1d(groups, "groups")
    if groups.shape != values.shape:
        raise ValueError(f"groups must match values, got {groups.shape} and {values.shape}")
    _, inverse = np.unique(groups, return_inverse=True)
    n_groups = int(inverse.max()) + 1
    if n_groups < min_groups:
        return float("nan"), float("nan")
    sums = np.bincount(inverse, weights=values, minlength=n_groups)
    counts = np.bincount(inverse, minlength=n_groups).astype(np.float64)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_groups, size=(n_resamples, n_groups))
    means = sums[draws].sum(axis=1) / counts[draws].sum(axis=1)
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(means, [alpha, 1.0 - alpha])
    return float(low), float(high)


CLUSTER_LEVELS: tuple[str, ...] = ("trial", "world")
"""The units the intervals resample (module docstring): the trials (``episode_id``) or the mazes
(``setup`` + ``world_seed``)."""


def check_cluster(cluster: str) -> str:
    """``cluster`` if it is one of :data:`CLUSTER_LEVELS` (ValueError naming them otherwise)."""
    if cluster not in CLUSTER_LEVELS:
        raise ValueError(f"cluster={cluster!r}: expected one of {', '.join(CLUSTER_LEVELS)}")
    return cluster


@dataclass
class RobotTrial:
    """One robot in one trial: the row written to the per-episode JSONL.

    ``steps`` is ``N_e``, ``collisions`` is ``N_c``, ``path_length`` is ``p`` and ``shortest_path`` is ``l``
    (metres); ``shortest_path_to_disc`` is the shortest path to the 1.5 m success disc instead of the target
    (kept for reference, not used by SPL); ``success_step`` is the 1-based step of success or ``None``;
    ``final_distance`` is the Euclidean distance to the target at the robot's last active step. ``measured``
    is False for robots that only play dynamic obstacles (paper Table III, unseen obstacles): they are
    recorded but left out of the aggregates.
    """

    method: str
    episode_id: str
    setup: str
    size: float
    n_robots: int
    world_seed: int
    trial: int
    robot: int
    robot_style: str
    measured: bool
    success: bool
    success_step: int | None
    steps: int
    collisions: int
    path_length: float
    shortest_path: float
    shortest_path_to_disc: float
    final_distance: float
    spl: float = field(init=False)
    collision_rate: float = field(init=False)

    def __post_init__(self) -> None:
        self.spl = float(spl_terms([self.success], [self.shortest_path], [self.path_length])[0])
        self.collision_rate = float(collision_rate_terms([self.collisions], [self.steps])[0])

    def to_dict(self) -> dict:
        """JSON-ready dict (plain Python types)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, row: dict) -> RobotTrial:
        """Inverse of :meth:`to_dict`; the derived ``spl`` / ``collision_rate`` are recomputed."""
        kwargs = {k: row[k] for k in cls.__dataclass_fields__ if k not in ("spl", "collision_rate")}
        return cls(**kwargs)


@dataclass(frozen=True)
class MetricSummary:
    """SR / SPL / CR over a set of robot-trials with ``(low, high)`` confidence intervals; an SPL / CR /
    SPL-disc interval is ``(nan, nan)`` when the records span too few clusters for one
    (:func:`min_trials_for_interval`). ``cluster`` is what the intervals resample (:data:`CLUSTER_LEVELS`);
    ``n_worlds`` counts the mazes (``setup`` + ``world_seed``)."""

    n_robot_trials: int
    n_trials: int
    n_worlds: int
    cluster: str
    sr: float
    sr_ci: tuple[float, float]
    spl: float
    spl_ci: tuple[float, float]
    cr: float
    cr_ci: tuple[float, float]
    spl_disc: float
    spl_disc_ci: tuple[float, float]


def summarize(
    records: Sequence[RobotTrial], confidence: float = 0.95, seed: int = 0, cluster: str = "trial"
) -> MetricSummary:
    """Aggregate the *measured* robot-trial records into SR, SPL, CR and their intervals.

    See the module docstring for the formulas; records with ``measured=False`` are skipped. ``cluster``
    (:data:`CLUSTER_LEVELS`): the intervals resample whole trials (``"trial"``) or whole mazes
    (``"world"``).
    """
    check_cluster(cluster)
    records = [r for r in records if r.measured]
    if len(records) == 0:
        raise ValueError("cannot summarise an empty list of (measured) robot-trials")
    success = np.array([r.success for r in records], dtype=bool)
    spl_values = spl_terms(
        success,
        np.array([r.shortest_path for r in records]),
        np.array([r.path_length for r in records]),
    )
    spl_disc_values = spl_terms(
        success,
        np.array([r.shortest_path_to_disc for r in records]),
        np.array([r.path_length for r in records]),
    )
    cr_values = collision_rate_terms(
        np.array([r.collisions for r in records]), np.array([r.steps for r in records])
    )
    _, trials = np.unique([r.episode_id for r in records], return_inverse=True)
    _, worlds = np.unique([f"{r.setup}/{r.world_seed}" for r in records], return_inverse=True)
    groups = trials if cluster == "trial" else worlds
    return MetricSummary(
        n_robot_trials=len(records),
        n_trials=int(trials.max()) + 1,
        n_worlds=int(worlds.max()) + 1,
        cluster=cluster,
        sr=success_rate(success),
        sr_ci=clustered_wilson_interval(success, groups, confidence),
        spl=float(spl_values.mean()),
        spl_ci=bootstrap_mean_interval(spl_values, groups, confidence, seed=seed),
        cr=float(cr_values.mean()),
        cr_ci=bootstrap_mean_interval(cr_values, groups, confidence, seed=seed + 1),
        spl_disc=float(spl_disc_values.mean()),
        spl_disc_ci=bootstrap_mean_interval(spl_disc_values, groups, confidence, seed=seed + 2),
    )


class TrialTracker:
    """Accumulates ``p``, ``N_c``, ``N_e`` and success per robot over one trial, step by step.

    Call :meth:`update` once per env step with the robots' poses *after* the step. A robot is active from
    the reset until (and including) the step on which it first succeeds; only active steps count.

    Args:
        start_xy: float ``[R, 2]`` robot positions right after the reset.
    """

    def __init__(self, start_xy: np.ndarray) -> None:
        start_xy = np.asarray(start_xy, dtype=np.float64)
        if start_xy.ndim != 2 or start_xy.shape[1] != 2:
            raise ValueError(f"start_xy must be [R, 2], got shape {start_xy.shape}")
        n = start_xy.shape[0]
        self._last_xy = start_xy.copy()
        self.path_length = np.zeros(n)
        self.collisions = np.zeros(n, dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.success = np.zeros(n, dtype=bool)
        self.success_step = np.full(n, -1, dtype=np.int64)
        self._t = 0

    @property
    def active(self) -> np.ndarray:
        """bool ``[R]``: robots that have not succeeded yet."""
        return ~self.success

    def update(
        self, xy: np.ndarray, collided: np.ndarray, succeeded: np.ndarray, driven: np.ndarray | None = None
    ) -> None:
        """Record one env step.

        Args:
            xy: float ``[R, 2]`` positions after the step.
            collided: bool ``[R]``, in contact on this step.
            succeeded: bool ``[R]``, within the success radius after this step (sticky or not).
            driven: optional float ``[R]``, the length each robot drove on this step (e.g. the arc length
                ``|v| * dt`` of its executed unicycle motion); default: the straight-line displacement
                ``||xy_t - xy_{t-1}||``.
        """
        xy = np.asarray(xy, dtype=np.float64)
        collided = np.asarray(collided, dtype=bool).reshape(-1)
        succeeded = np.asarray(succeeded, dtype=bool).reshape(-1)
        if xy.shape != self._last_xy.shape or not collided.shape == succeeded.shape == self.success.shape:
            raise ValueError(f"expected xy {self._last_xy.shape} and flags [{len(self.success)}]")
        if not np.all(np.isfinite(xy)):
            raise ValueError(f"xy must be finite, got {xy}")
        if driven is None:
            driven = np.linalg.norm(xy - self._last_xy, axis=1)
        driven = np.asarray(driven, dtype=np.float64).reshape(-1)
        if driven.shape != self.success.shape or not np.all(np.isfinite(driven) & (driven >= 0)):
            raise ValueError(f"driven must be [{len(self.success)}] finite lengths >= 0, got {driven}")
        # every input is checked before any count changes: a refused call leaves the tracker as it was
        self._t += 1
        active = self.active
        self.steps += active
        self.collisions += active & collided
        self.path_length += np.where(active, driven, 0.0)
        newly = active & succeeded
        self.success_step[newly] = self._t
        self.success |= newly
        self._last_xy = xy.copy()


def _as_1d(x, name: str) -> np.ndarray:
    arr = np.asarray(x)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    return arr


def _normal_quantile(confidence: float) -> float:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)
