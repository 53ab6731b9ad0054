"""Episode metrics on hand-made paths and layouts (numpy only)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from deck_sim.geometry import Footprints
from deck_sim.metrics import (
    Z95,
    mean_interval,
    near_misses,
    paired_bootstrap_interval,
    path_length,
    rate_interval,
    shortest_path,
    t975,
    turning_angle,
)

BOUNDS = np.array([[-100.0, -100.0], [100.0, 100.0]])


def box(cx: float, cy: float, hx: float, hy: float) -> Footprints:
    return Footprints(np.array([[cx, cy]]), np.array([[hx, hy]]), np.zeros(1), np.zeros(1))


def test_a_straight_path_has_its_length_and_no_turn():
    xy = np.column_stack([np.linspace(0, 30, 31), np.zeros(31)])
    assert path_length(xy) == pytest.approx(30.0)
    assert turning_angle(xy) == pytest.approx(0.0)


def test_a_right_angle_turn_turns_ninety_degrees():
    xy = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [10.0, 5.0], [10.0, 10.0]])
    assert path_length(xy) == pytest.approx(20.0)
    assert math.degrees(turning_angle(xy)) == pytest.approx(90.0)


def test_standing_still_adds_no_turn():
    jitter = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.01], [0.01, 0.01], [10.0, 0.0], [20.0, 0.0]])
    assert turning_angle(jitter) == pytest.approx(0.0)


def test_shortest_path_goes_round_a_wall_by_its_corner():
    # a wall from y=-5 to y=5 at x=0, 2 m thick; a point agent from (-10, 0) to (10, 0) passes its corners
    wall = box(0.0, 0.0, 1.0, 5.0)
    length = shortest_path(wall, 0.0, BOUNDS, np.array([-10.0, 0.0]), np.array([10.0, 0.0]))
    expected = 2 * math.hypot(9.0, 5.0) + 2.0
    # graph nodes sit 5 cm outside the octagons' vertices (VisibilityGraph.node_margin): a few cm longer
    assert expected <= length <= expected + 0.1


def test_shortest_path_is_straight_in_the_open_and_nan_when_walled_in():
    empty = Footprints.empty()
    assert shortest_path(empty, 1.0, BOUNDS, np.zeros(2), np.array([3.0, 4.0])) == pytest.approx(5.0)
    # a wall across the whole surface: no way through for a disc of 1 m
    across = box(0.0, 0.0, 1.0, 100.0)
    assert math.isnan(shortest_path(across, 1.0, BOUNDS, np.array([-10.0, 0.0]), np.array([10.0, 0.0])))


def test_a_path_that_collides_shows_in_clearance_and_near_misses():
    # clearance along a pass that touches an obstacle (negative: overlap) and a later close pass
    clearance = np.array([8.0, 5.0, 1.0, -0.4, 0.5, 3.0, 6.0, 1.2, 0.9, 4.0])
    assert near_misses(clearance, 1.0) == 2  # the collision pass and the 0.9 m pass count once each
    assert near_misses(clearance, 0.0) == 1
    assert near_misses(np.array([0.2, 0.3, 5.0]), 1.0) == 1  # starts close: counts
    assert near_misses(np.array([]), 1.0) == 0


def test_wilson_intervals_by_hand():
    lo, hi = rate_interval(5, 10)
    assert (lo, hi) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    lo, hi = rate_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    assert rate_interval(10, 10)[1] == pytest.approx(1.0)
    assert all(math.isnan(v) for v in rate_interval(0, 0))
    with pytest.raises(ValueError, match="successes"):
        rate_interval(11, 10)


outcomes = st.integers(1, 4).flatmap(
    lambda seeds: st.integers(1, 30).flatmap(
        lambda eps: st.tuples(*[st.lists(st.lists(st.integers(0, 1), min_size=eps, max_size=eps),
                                         min_size=seeds, max_size=seeds)] * 2)
    )
)


@settings(max_examples=40, deadline=None)
@given(outcomes, st.floats(-3.0, 3.0))
def test_paired_bootstrap_is_antisymmetric_and_moves_with_a_shift(pair, shift):
    a, b = (np.array(x, dtype=np.float64) for x in pair)
    m, lo, hi = paired_bootstrap_interval(a, b, resamples=500, seed=3)
    assert lo <= hi and -1.0 <= lo and hi <= 1.0
    assert m == pytest.approx(float((a - b).mean()))
    # the same resamples: swapping the agents mirrors the interval, shifting one shifts it
    assert paired_bootstrap_interval(b, a, resamples=500, seed=3) == pytest.approx((-m, -hi, -lo))
    assert paired_bootstrap_interval(a + shift, b, resamples=500, seed=3) == pytest.approx((m + shift, lo + shift,
                                                                                           hi + shift))
    assert paired_bootstrap_interval(a, a, resamples=500, seed=3) == (0.0, 0.0, 0.0)


def test_paired_bootstrap_widens_where_seeds_agree_but_episodes_differ():
    # three seeds each 5 points apart: the t interval over seeds has no width, the bootstrap carries the episodes
    rng = np.random.default_rng(0)
    b = (rng.random((3, 100)) < 0.8).astype(float)
    a = b.copy()
    for row in a:
        row[np.flatnonzero(row == 0)[:5]] = 1.0  # five more successes on each seed
    assert mean_interval((a - b).mean(axis=1)) == pytest.approx((0.05, 0.05, 0.05))
    m, lo, hi = paired_bootstrap_interval(a, b)
    assert m == pytest.approx(0.05) and 0.0 < lo < 0.05 < hi < 0.1
    # an agent that wins on some episodes and loses on others by the same net count: wider still, across zero
    c = b.copy()
    for row in c:
        ones, zeros = np.flatnonzero(row == 1), np.flatnonzero(row == 0)
        row[zeros[:10]], row[ones[:5]] = 1.0, 0.0
    m2, lo2, hi2 = paired_bootstrap_interval(c, b)
    assert m2 == pytest.approx(0.05) and lo2 < lo and hi2 > hi
    assert paired_bootstrap_interval(c, b) == (m2, lo2, hi2)  # seeded: the same interval every time


def test_paired_bootstrap_resamples_the_seeds():
    # all the difference lies between the two seeds: an interval over episodes alone would have no width
    a = np.array([[1.0] * 50, [0.0] * 50])
    assert paired_bootstrap_interval(a, np.zeros_like(a)) == (0.5, 0.0, 1.0)


def test_paired_bootstrap_counts_an_episode_played_by_every_seed_once():
    # every seed plays the same episodes: one seed's outcomes repeated three times carry no more information
    # than that seed alone, and the interval is as wide (drawing each seed's episodes apart would narrow it by
    # the square root of three)
    rng = np.random.default_rng(1)
    a, b = (rng.random((1, 100)) < p for p in (0.85, 0.8))
    _, lo1, hi1 = paired_bootstrap_interval(a, b)
    _, lo3, hi3 = paired_bootstrap_interval(np.repeat(a, 3, axis=0), np.repeat(b, 3, axis=0))
    assert (hi3 - lo3) == pytest.approx(hi1 - lo1, rel=0.15)


def test_paired_bootstrap_matches_the_standard_error_over_several_chunks():
    # 2 x 1000 values resample in several chunks; the two rows agree, so the interval is that of 1000 episodes,
    # whose half-width is close to 1.96 standard errors of their mean
    rng = np.random.default_rng(2)
    d = (rng.random(1000) < 0.3).astype(float) - (rng.random(1000) < 0.2).astype(float)
    a = np.repeat(d[None, :], 2, axis=0)
    m, lo, hi = paired_bootstrap_interval(a, np.zeros_like(a))
    assert m == pytest.approx(d.mean())
    assert (hi - lo) / 2 == pytest.approx(1.96 * d.std() / np.sqrt(d.size), rel=0.1)


def test_paired_bootstrap_refuses_unpaired_shapes_by_name():
    with pytest.raises(ValueError, match=r"\(seeds, episodes\) arrays of one shape"):
        paired_bootstrap_interval(np.zeros((2, 5)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="seeds, episodes"):
        paired_bootstrap_interval(np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError, match="resamples must be at least 1"):
        paired_bootstrap_interval(np.zeros((1, 2)), np.zeros((1, 2)), resamples=0)
    assert all(math.isnan(v) for v in paired_bootstrap_interval(np.zeros((0, 0)), np.zeros((0, 0))))


def test_mean_interval_by_hand():
    m, lo, hi = mean_interval([1.0, 2.0, 3.0, 4.0])
    half = 3.1824 * np.std([1, 2, 3, 4], ddof=1) / 2.0  # Student's t, 3 degrees of freedom
    assert (m, lo, hi) == pytest.approx((2.5, 2.5 - half, 2.5 + half))
    assert mean_interval([7.0]) == (7.0, 7.0, 7.0)
    assert all(math.isnan(v) for v in mean_interval([]))


coords = st.floats(-50, 50, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(coords, coords), min_size=2, max_size=12), st.floats(-math.pi, math.pi), coords, coords)
def test_length_and_turning_do_not_depend_on_the_frame(points, yaw, dx, dy):
    xy = np.array(points)
    c, s = math.cos(yaw), math.sin(yaw)
    moved = xy @ np.array([[c, s], [-s, c]]) + np.array([dx, dy])
    assert path_length(moved) == pytest.approx(path_length(xy), rel=1e-9, abs=1e-9)
    assert turning_angle(moved) == pytest.approx(turning_angle(xy), rel=1e-6, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(coords, coords, st.floats(0.5, 8), st.floats(0.5, 8), st.floats(0.0, 2.0))
def test_shortest_path_lies_between_the_straight_line_and_a_detour(cx, cy, hx, hy, radius):
    start, goal = np.array([-70.0, 0.0]), np.array([70.0, 0.0])
    fp = box(cx, cy, hx, hy)
    length = shortest_path(fp, radius, BOUNDS, start, goal)
    straight = float(np.linalg.norm(goal - start))
    assert length >= straight - 1e-9
    # going round over the top of the box's grown octagon is always possible and no shorter
    top = cy + hy + radius + 1.0 + (hx + radius)  # above the octagon's diagonal faces
    detour = path_length(np.array([start, [cx - hx - radius - 1, top], [cx + hx + radius + 1, top], goal]))
    assert length <= detour + 1e-6


def test_t_quantiles_match_scipy():
    stats = pytest.importorskip("scipy.stats")
    for df in (1, 2, 5, 29, 30, 31, 45, 100, 1000):
        assert t975(df) == pytest.approx(float(stats.t.ppf(0.975, df)), abs=2e-4)
    assert t975(10**9) == pytest.approx(Z95, abs=1e-6)
    with pytest.raises(ValueError):
        t975(0)
