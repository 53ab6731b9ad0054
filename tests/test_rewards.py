"""Property tests of the paper's reward terms (eq. 10-16) with deck_sim's sign decision for r2."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.tasks import rewards

dist = st.floats(0, 500, allow_nan=False)
bounds = st.tuples(st.floats(0.001, 1), st.floats(1, 10))


@given(before=dist, after=dist, lohi=bounds, deadband=st.floats(0, 0.05))
def test_attraction_has_the_sign_of_progress_and_a_bounded_magnitude(before, after, lohi, deadband):
    lo, hi = lohi
    r1 = rewards.attraction(before, after, lo, hi, deadband)
    progress = before - after
    if abs(progress) < deadband:
        assert r1 == 0.0
    else:
        assert (r1 > 0) == (progress >= 0)  # the paper's d >= 0 branch is the positive one
        assert lo - 1e-12 <= abs(r1) <= hi + 1e-12
        if lo <= abs(progress) <= hi:
            assert r1 == pytest.approx(progress)


@given(
    c_before=st.lists(st.floats(-5, 50), min_size=1, max_size=8),
    shift=st.floats(-3, 3),
    influence=st.floats(0.5, 20),
    lohi=bounds,
)
def test_repulsion_rewards_moving_away_from_the_nearest_obstacle_inside_the_influence_radius(
    c_before, shift, influence, lohi
):
    lo, hi = lohi
    before = np.array(c_before)
    after = before + shift
    r2 = rewards.repulsion(before, after, influence, lo, hi, deadband=0.0)
    if after.min() >= influence:
        assert r2 == 0.0
    else:
        j = int(np.argmin(after))
        assert (r2 > 0) == (
            after[j] - before[j] >= 0
        )  # away (clearance grows) is rewarded, closing in penalised
        assert lo - 1e-12 <= abs(r2) <= hi + 1e-12


def test_repulsion_without_obstacles_is_zero():
    assert rewards.repulsion(np.zeros(0), np.zeros(0), 5.0, 0.1, 1.0, 0.0) == 0.0


@given(
    r1=st.floats(-5, 5),
    r2=st.floats(-5, 5),
    collided=st.booleans(),
    reached=st.booleans(),
    w=st.tuples(*[st.floats(0, 2)] * 4),
)
def test_total_is_the_weighted_sum_of_eq_16(r1, r2, collided, reached, w):
    t = rewards.total_reward(r1, r2, collided, reached, -50.0, 200.0, w)
    assert t.r3 == (-50.0 if collided else 0.0) and t.r4 == (200.0 if reached else 0.0)
    assert t.total == pytest.approx(w[0] * r1 + w[1] * r2 + w[2] * t.r3 + w[3] * t.r4)


def test_non_finite_progress_is_refused():
    with pytest.raises(ValueError, match="non-finite"):
        rewards.attraction(np.nan, 1.0, 0.1, 1.0, 0.0)


@given(
    n=st.integers(1, 5),
    k=st.integers(1, 10),
    seed=st.integers(0, 2**32 - 1),
    dt=st.floats(0.1, 1.0),
)
def test_a_lookahead_clearance_is_the_closest_approach_and_never_more_than_now(n, k, seed, dt):
    rng = np.random.default_rng(seed)
    clear, agent, vel = rng.uniform(0, 30, n), rng.uniform(-50, 50, 2), rng.uniform(-5, 5, 2)
    movers, forecast = rng.uniform(-50, 50, (n, 2)), rng.uniform(-50, 50, (n, k, 2))
    out = rewards.lookahead_clearances(clear, agent, vel, movers, forecast, dt)
    assert np.all(out <= clear)
    for j in range(n):  # the closest approach over the K steps, counted against the distance now
        gaps = [np.linalg.norm(forecast[j, i] - (agent + (i + 1) * dt * vel)) for i in range(k)]
        now = np.linalg.norm(movers[j] - agent)
        assert out[j] == pytest.approx(clear[j] + min(min(gaps) - now, 0.0), abs=1e-9)


@given(gap=st.floats(26, 60), speed=st.floats(0.5, 5), k=st.integers(1, 10))
def test_a_mover_driving_at_a_standing_agent_counts_as_nearer_and_one_driving_away_as_now(gap, speed, k):
    agent, still = np.zeros(2), np.zeros(2)
    mover = np.array([[gap, 0.0]])
    steps = np.arange(1, k + 1)[:, None] * 0.5 * speed
    towards = (mover[0] - steps * [1.0, 0.0])[None]
    away = (mover[0] + steps * [1.0, 0.0])[None]
    near = rewards.lookahead_clearances(np.array([gap - 2.0]), agent, still, mover, towards, 0.5)
    assert near[0] == pytest.approx(gap - 2.0 - k * 0.5 * speed, abs=1e-9)  # (it stops short of the agent)
    assert rewards.lookahead_clearances(np.array([gap - 2.0]), agent, still, mover, away, 0.5)[0] == gap - 2.0
