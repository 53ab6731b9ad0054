"""Prioritised replay (``per_alpha``): rows are drawn in proportion to their priority with the importance-sampling
weights of Schaul et al. (2016), priorities follow the last TD errors, the critic weighs its errors, and a run
with it resumes exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import short_config
from tests.training_runs import assert_same_run
from training.buffers import ReplayBuffer
from training.config import ConfigError, make_config
from training.loop import Trainer


def _buffer(n: int, demos: int = 0) -> ReplayBuffer:
    buf = ReplayBuffer(n + demos + 4, 3, 2, prioritised=True)
    z = np.zeros
    if demos:
        buf.add_demos(z((demos, 3)), z((demos, 2)), z(demos), z((demos, 3)), z(demos))
    obs = np.arange(n, dtype=np.float32)[:, None].repeat(3, axis=1)
    buf.add(obs, z((n, 2)), z(n), obs, z(n))
    return buf


def test_rows_are_drawn_in_proportion_to_their_priority():
    buf = _buffer(4)
    assert np.all(buf.priority[:4] == 1.0)  # new rows at the largest priority so far
    buf.update_priorities(np.arange(4), np.array([0.0, 1.0, 3.0, -7.0]), alpha=1.0, eps=1.0)
    np.testing.assert_allclose(buf.priority[:4], [1.0, 2.0, 4.0, 8.0])
    assert buf.max_priority == 8.0
    rows, weights = buf.prioritised_rows(60_000, np.random.default_rng(0), beta=1.0)
    share = np.bincount(rows, minlength=4) / len(rows)
    np.testing.assert_allclose(share, np.array([1, 2, 4, 8]) / 15, atol=0.01)
    # weight (N P(i))^-beta over the largest: the rarest row weighs 1, the most frequent 1/8
    by_row = {int(r): float(w) for r, w in zip(rows, weights, strict=True)}
    np.testing.assert_allclose([by_row[i] for i in range(4)], [1.0, 0.5, 0.25, 0.125], rtol=1e-6)
    buf.add(np.ones((1, 3)), np.zeros((1, 2)), np.zeros(1), np.ones((1, 3)), np.zeros(1))
    assert buf.priority[4] == 8.0


@settings(max_examples=30, deadline=None)
@given(
    errors=st.lists(st.floats(-50, 50, allow_nan=False), min_size=3, max_size=30),
    beta=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31),
)
def test_weights_lie_in_0_1_and_demonstrations_stay_uniform(errors, beta, seed):
    n = len(errors)
    buf = _buffer(n, demos=5)
    buf.update_priorities(5 + np.arange(n), np.array(errors), alpha=0.6, eps=1e-3)
    rows, weights = buf.prioritised_rows(64, np.random.default_rng(seed), demo_fraction=0.25, beta=beta)
    assert rows.shape == weights.shape == (64,)
    assert np.all(rows[:16] < 5) and np.all(rows[16:] >= 5) and np.all(rows < buf.size)
    assert np.all(weights[:16] == 1.0)
    assert np.all(weights > 0.0) and np.all(weights <= 1.0) and weights[16:].max() == 1.0
    buf.update_priorities(rows, np.full(64, 2.0), alpha=1.0, eps=0.0)
    assert np.all(buf.priority[rows[16:]] == 2.0)


def test_checkpointed_priorities_come_back():
    buf = _buffer(6)
    buf.update_priorities(np.arange(6), np.arange(6.0), alpha=0.5, eps=0.1)
    again = ReplayBuffer(buf.capacity, 3, 2, prioritised=True)
    again.load_state_dict(buf.state_dict())
    np.testing.assert_array_equal(again.priority[:6], buf.priority[:6])
    assert again.max_priority == buf.max_priority
    with pytest.raises(ValueError, match="lacks priority"):
        again.load_state_dict(ReplayBuffer(buf.capacity, 3, 2).state_dict())


def test_prioritised_replay_settings_are_checked():
    for field, value in (("per_alpha", 1.5), ("per_beta", -0.1), ("per_eps", 0.0)):
        with pytest.raises(ConfigError, match=field):
            make_config("reward", **{field: value})
    assert make_config("reward", per_alpha=0.6).regime == "reward"


@pytest.mark.slow
def test_a_prioritised_run_learns_from_its_td_errors_and_resumes_exactly(tmp_path):
    cfg = short_config(demo_episodes=0, pretrain_updates=0, bc_weight=0.0, expert_relabel=False, per_alpha=0.6)
    whole = Trainer(cfg, tmp_path / "whole", progress=False)
    whole.train()
    agent_rows = whole.buffer.priority[whole.buffer.n_demo : whole.buffer.size]
    assert whole.buffer.prioritised and len(np.unique(agent_rows)) > 10  # priorities follow the TD errors
    first = Trainer(cfg, tmp_path / "broken", progress=False)
    first.train(stop_at=70)
    resumed = Trainer(cfg, tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
    np.testing.assert_array_equal(resumed.buffer.priority, whole.buffer.priority)
