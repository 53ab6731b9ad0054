"""Episode metrics (numpy only): path length, turning angle, outcome rates, clearance, prediction error.

Angles are radians inside; ``summarize`` reports turning angles in degrees, as the paper does. ``shortest_path``
is the reference a path length is compared with (the paper's Unity units differ from metres), ``near_misses``
counts close passes, ``rate_interval`` and ``mean_interval`` give the 95 % confidence intervals of the evaluation
tables, ``paired_bootstrap_interval`` that of a difference between two agents over training seeds and episodes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from deck_sim.geometry import Footprints, NoPathError, VisibilityGraph

OUTCOMES = ("goal", "collision", "off_surface", "timeout", "diverged")


def path_length(xy: np.ndarray) -> float:
    """Length in metres of a planar path (T, 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 2:
        return 0.0
    return float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))


def turning_angle(xy: np.ndarray, min_segment: float = 0.05) -> float:
    """Total absolute change of direction along a planar path (T, 2), radians.

    Directions are taken between consecutive samples at least ``min_segment`` metres apart, so a vehicle
    standing still (numerical jitter) adds nothing.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 3:
        return 0.0
    kept = [xy[0]]
    for p in xy[1:]:
        if np.hypot(*(p - kept[-1])) >= min_segment:
            kept.append(p)
    if len(kept) < 3:
        return 0.0
    seg = np.diff(np.array(kept), axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    change = (np.diff(heading) + np.pi) % (2.0 * np.pi) - np.pi
    return float(np.sum(np.abs(change)))


def shortest_path(statics: Footprints, radius: float, bounds: np.ndarray, start: np.ndarray, goal: np.ndarray) -> float:
    """Length in metres of the shortest path from ``start`` to ``goal`` that keeps a disc of ``radius`` metres
    clear of the static obstacles and on the surface ``bounds`` ((xmin, ymin), (xmax, ymax)).

    Obstacles are taken as their enclosing octagons (``VisibilityGraph``), so the length is at most a few per cent
    above the exact one around rounded rectangles. A start or goal inside a grown obstacle may leave or enter it
    straight. NaN if no path exists.
    """
    try:
        path = VisibilityGraph(statics, float(radius), np.asarray(bounds, dtype=np.float64)).shortest_path(
            np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
        )
    except NoPathError:
        return float("nan")
    return path_length(path)


def near_misses(clearance: np.ndarray, threshold: float) -> int:
    """Number of close passes in a clearance series (T,): the times it falls below ``threshold`` metres.

    A pass that stays close over several steps counts once; a series starting below the threshold starts with one.
    """
    close = np.asarray(clearance, dtype=np.float64) < threshold
    if close.size == 0:
        return 0
    return int(close[0]) + int(np.count_nonzero(close[1:] & ~close[:-1]))


Z95 = 1.959963984540054
"""The two-sided 95 % quantile of the standard normal distribution."""


def rate_interval(successes: int, trials: int) -> tuple[float, float]:
    """Wilson score 95 % interval (low, high) of a rate of ``successes`` in ``trials``; (NaN, NaN) for none.

    Unlike the normal approximation it stays inside [0, 1] and does not collapse to a point at 0 % or 100 %.
    """
    if trials <= 0:
        return float("nan"), float("nan")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must lie in [0, {trials}], got {successes}")
    p = successes / trials
    z2 = Z95 * Z95
    centre = (p + z2 / (2 * trials)) / (1 + z2 / trials)
    half = Z95 * np.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials)) / (1 + z2 / trials)
    return float(max(centre - half, 0.0)), float(min(centre + half, 1.0))


_T975 = (12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.306, 2.2622, 2.2281, 2.201, 2.1788, 2.1604,
         2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.093, 2.086, 2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555,
         2.0518, 2.0484, 2.0452, 2.0423)  # fmt: skip


def t975(df: int) -> float:
    """The 97.5 % quantile of Student's t distribution with ``df`` degrees of freedom (two-sided 95 %).

    Tabulated to 4 decimals up to 30 degrees of freedom; beyond, the Cornish-Fisher expansion about the normal
    quantile (error below 1e-4).
    """
    if df < 1:
        raise ValueError(f"degrees of freedom must be at least 1, got {df}")
    if df <= len(_T975):
        return _T975[df - 1]
    z = Z95
    return float(
        z
        + (z**3 + z) / (4 * df)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * df**3)
    )


def mean_interval(values: Sequence[float]) -> tuple[float, float, float]:
    """(mean, low, high): the mean of ``values`` and its 95 % interval, Student's t with n - 1 degrees of freedom.

    NaN for no values; the interval is the mean itself for one value (no spread can be estimated).
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    m = float(x.mean())
    if x.size == 1:
        return m, m, m
    half = t975(x.size - 1) * float(x.std(ddof=1)) / np.sqrt(x.size)
    return m, float(m - half), float(m + half)


def paired_bootstrap_interval(
    a: np.ndarray, b: np.ndarray, resamples: int = 10_000, seed: int = 0
) -> tuple[float, float, float]:
    """(mean, low, high): the mean difference ``a - b`` and its 95 % interval over training seeds and episodes.

    Args:
        a, b: (seeds, episodes) per-episode values of two agents (1.0 for a success, 0.0 otherwise, or any
            per-episode figure). Row k of both comes from training seed k (the two agents' runs are paired by seed)
            and column j from held-out episode j, the same episode for both agents and for every seed.
        resamples: Bootstrap resamples.
        seed: Seed of the resampling, so that a table prints the same interval every time.

    Seeds and episodes are crossed (every seed plays the same episodes), so each resample draws the seeds with
    replacement and, apart from them, the episodes with replacement, the same drawn episodes for every drawn seed and
    both agents; the interval is the 2.5 and 97.5 percentiles of the resampled mean differences. This is the
    pigeonhole bootstrap of crossed random effects (Owen 2007, "The pigeonhole bootstrap", Ann. Appl. Stat.): it
    carries the spread between training seeds, the sampling of episodes (an episode that favours one agent on every
    seed counts as one episode) and their interaction, and errs on the wide side for the latter two. A Student-t
    interval over the seeds' mean differences (``mean_interval``) leaves the episodes out: three seeds whose
    differences happen to agree give it no width at all. With few seeds the bootstrap understates the spread
    between seeds (by the factor (n - 1) / n of its variance), so tables give it beside the interval over seeds,
    not in its place. One seed: only the episodes are resampled. NaN for no values.

    Raises:
        ValueError: ``a`` and ``b`` differ in shape or are not two-dimensional, or ``resamples`` is below 1.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"a and b must be (seeds, episodes) arrays of one shape, got {a.shape} and {b.shape}")
    if resamples < 1:
        raise ValueError(f"resamples must be at least 1, got {resamples}")
    if a.size == 0:
        return float("nan"), float("nan"), float("nan")
    d = a - b
    n_seeds, n_episodes = d.shape
    rng = np.random.default_rng(seed)
    means = np.empty(resamples)
    chunk = max(1, 4_000_000 // d.size)  # (bounds the gathered (k, seeds, episodes) array to a few tens of MB)
    for start in range(0, resamples, chunk):
        k = min(chunk, resamples - start)
        rows = rng.integers(0, n_seeds, size=(k, n_seeds, 1))
        cols = rng.integers(0, n_episodes, size=(k, 1, n_episodes))  # (the same episodes for every seed)
        means[start:start + k] = d[rows, cols].mean(axis=(1, 2))
    low, high = np.percentile(means, [2.5, 97.5])
    return float(d.mean()), float(low), float(high)


def prediction_errors(predicted: np.ndarray, actual: np.ndarray) -> tuple[float, float, int]:
    """Average and final displacement errors (ADE, FDE; metres) of an episode's mover predictions.

    Args:
        predicted: (T, n, N, 2) at every step t, the predicted positions of the n movers at steps t+1 ... t+N.
        actual: (T, n, 2) the movers' positions at every step.

    Returns:
        (ADE, FDE, samples): ADE averages the error over every predicted step, FDE the error at step N, both over
        every mover and every step t whose horizon ends within the episode (t + N <= T - 1); ``samples`` counts
        the (step, mover) pairs scored. ADE and FDE are NaN when none is.
    """
    predicted = np.asarray(predicted, dtype=np.float64)
    actual = np.asarray(actual, dtype=np.float64)
    steps, n, horizon = predicted.shape[0], predicted.shape[1], predicted.shape[2]
    scored = steps - horizon
    if horizon == 0 or n == 0 or scored <= 0:
        return float("nan"), float("nan"), 0
    truth = np.stack([actual[t + 1 : t + horizon + 1] for t in range(scored)]).transpose(0, 2, 1, 3)
    err = np.hypot(*(predicted[:scored] - truth).transpose(3, 0, 1, 2))  # (scored, n, N)
    return float(err.mean()), float(err[..., -1].mean()), scored * n


@dataclass(frozen=True)
class EpisodeResult:
    """What one episode came to. Lengths in metres, times in seconds, angles in degrees."""

    scene: str
    episode: int
    outcome: str
    """One of ``OUTCOMES``."""
    steps: int
    sim_time: float
    reward: float
    path_length: float
    start_target_distance: float
    turning_angle_deg: float
    min_clearance: float
    collision_partner: str | None
    predictor_fallbacks: int

    def as_dict(self) -> dict:
        """Plain dict (JSON/CSV friendly)."""
        return asdict(self)


def outcome_of(info: dict, truncated: bool) -> str:
    """Outcome label of an episode from the task's last ``info`` and whether the time limit ended it."""
    if info.get("diverged"):
        return "diverged"
    if info.get("collision"):
        return "collision"
    if info.get("left_surface"):
        return "off_surface"
    if info.get("reached_goal"):
        return "goal"
    if truncated:
        return "timeout"
    raise ValueError(f"episode ended without an outcome: {info}")


def summarize(results: Sequence[EpisodeResult]) -> dict[str, float]:
    """Rates of every outcome, mean reward, and mean path length and turning angle of successful episodes."""
    if not results:
        raise ValueError("no episodes to summarize")
    n = len(results)
    out: dict[str, float] = {"episodes": float(n)}
    for o in OUTCOMES:
        out[f"{o}_rate"] = sum(r.outcome == o for r in results) / n
    ok = [r for r in results if r.outcome == "goal"]
    out["mean_reward"] = float(np.mean([r.reward for r in results]))
    out["path_length"] = float(np.mean([r.path_length for r in ok])) if ok else float("nan")
    out["path_ratio"] = (
        float(np.mean([r.path_length / max(r.start_target_distance, 1e-9) for r in ok])) if ok else float("nan")
    )
    out["turning_angle_deg"] = float(np.mean([r.turning_angle_deg for r in ok])) if ok else float("nan")
    out["time_to_goal"] = float(np.mean([r.sim_time for r in ok])) if ok else float("nan")
    out["min_clearance"] = float(np.min([r.min_clearance for r in results]))
    return out


@dataclass(frozen=True)
class TeamEpisodeResult:
    """What one episode of several aircraft came to (``deck_sim.tasks.multi``). Lengths in metres, times in
    seconds.

    ``aircraft`` holds one ``EpisodeResult`` per aircraft: its own outcome, its path up to the step it was done
    (``sim_time`` is then), its reward; ``collision_partner`` names what it hit, another aircraft included."""

    scene: str
    episode: int
    aircraft: tuple[EpisodeResult, ...]
    shortest: tuple[float, ...]
    """Per aircraft, the length of the shortest way from its start to its target's disc around the static
    obstacles (``shortest_path`` for its narrowest half-width, less the goal radius): the lower bound of its path."""
    makespan: float
    """Seconds until the last aircraft arrived; NaN unless every one did."""
    aircraft_collisions: int
    """Collisions between two aircraft (each pair counted once)."""

    @property
    def all_reached(self) -> bool:
        """Whether every aircraft reached its target."""
        return all(r.outcome == "goal" for r in self.aircraft)

    def as_dict(self) -> dict:
        """Plain dict (JSON friendly)."""
        return asdict(self)


def summarize_team(results: Sequence[TeamEpisodeResult]) -> dict[str, float]:
    """Per-aircraft outcome rates (over every aircraft of every episode), the share of episodes in which every
    aircraft arrived, their mean makespan, aircraft-aircraft collisions per episode, and the sum of the paths
    against the sum of the shortest ways (episodes in which every aircraft arrived)."""
    if not results:
        raise ValueError("no episodes to summarize")
    aircraft = [r for team in results for r in team.aircraft]
    out: dict[str, float] = {"episodes": float(len(results)), "aircraft": float(len(aircraft))}
    for o in OUTCOMES:
        out[f"{o}_rate"] = sum(r.outcome == o for r in aircraft) / len(aircraft)
    full = [team for team in results if team.all_reached]
    out["all_reached_rate"] = len(full) / len(results)
    out["makespan"] = float(np.mean([team.makespan for team in full])) if full else float("nan")
    out["aircraft_collisions_per_episode"] = float(np.mean([team.aircraft_collisions for team in results]))
    paths = [sum(r.path_length for r in team.aircraft) for team in full]
    bounds = [sum(team.shortest) for team in full]
    out["path_sum_ratio"] = float(np.sum(paths) / np.sum(bounds)) if full and np.sum(bounds) > 0 else float("nan")
    out["mean_reward"] = float(np.mean([r.reward for r in aircraft]))
    return out

