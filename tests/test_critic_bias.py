"""``benchmarks/critic_bias.py``: Monte Carlo returns followed through a replay buffer in any row order, and the
report of a real run's critic against them."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import short_config
from hypothesis import given, settings
from hypothesis import strategies as st

from training.loop import Trainer

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("critic_bias", ROOT / "benchmarks" / "critic_bias.py")
sys.path.insert(0, str(ROOT / "benchmarks"))
critic_bias = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(critic_bias)


def _episodes() -> tuple[np.ndarray, ...]:
    """Two episodes of one-number states: 0 -> 1 -> 2 (ends, reward 10) and 5 -> 6 (cut: no end), rewards 1, 2."""
    obs = np.array([[0.0], [1.0], [2.0], [5.0], [6.0]], dtype=np.float32)
    next_obs = np.array([[1.0], [2.0], [3.0], [6.0], [7.0]], dtype=np.float32)
    reward = np.array([1.0, 2.0, 10.0, 1.0, 2.0], dtype=np.float32)
    terminated = np.array([0.0, 0.0, 1.0, 0.0, 0.0], dtype=np.float32)
    return obs, next_obs, reward, terminated


@settings(max_examples=30, deadline=None)
@given(st.permutations(range(5)))
def test_monte_carlo_returns_follow_each_episode_to_its_end_in_any_row_order(order):
    obs, next_obs, reward, terminated = (a[list(order)] for a in _episodes())
    g, repeated = critic_bias.monte_carlo_returns(obs, next_obs, reward, terminated, gamma=0.5, scale=0.1)
    assert repeated == 0
    by_state = {float(o[0]): v for o, v in zip(obs, g, strict=True)}
    np.testing.assert_allclose([by_state[2.0], by_state[1.0], by_state[0.0]],
                               [1.0, 0.2 + 0.5 * 1.0, 0.1 + 0.5 * (0.2 + 0.5)], rtol=1e-6)
    assert np.isnan(by_state[5.0]) and np.isnan(by_state[6.0])  # never reaches an end


def test_a_repeated_observation_cuts_the_returns_that_would_pass_through_it():
    # a standstill: 0 -> 1, 1 -> 1 (the same observation again), 1 -> 2 (ends); which row of 1 follows is a guess
    obs = np.array([[0.0], [1.0], [1.0]], dtype=np.float32)
    next_obs = np.array([[1.0], [1.0], [2.0]], dtype=np.float32)
    g, repeated = critic_bias.monte_carlo_returns(obs, next_obs, np.array([1.0, 0.0, 5.0]), np.array([0.0, 0.0, 1.0]),
                                                  gamma=0.9, scale=1.0)
    assert repeated == 2
    assert np.isnan(g[0]) and np.isnan(g[1]) and g[2] == 5.0


def test_a_runs_critic_is_compared_with_its_buffers_returns_and_a_folder_without_checkpoint_is_named(tmp_path):
    cfg = short_config(
        algo="ddpg", total_steps=600, num_envs=2, demo_episodes=0, pretrain_updates=0, bc_weight=0.0,
        expert_relabel=False, twin_critics=True, target_noise=0.2, policy_delay=2, twin_min_weight=0.5,
    )
    run = tmp_path / "run"
    trainer = Trainer(cfg, run, progress=False)
    trainer.train()
    trainer.close()
    done = subprocess.run(
        [sys.executable, "benchmarks/critic_bias.py", str(run), str(tmp_path / "empty"), "--samples", "50"],
        cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}, capture_output=True,
        text=True, timeout=300,
    )
    assert done.returncode == 1
    assert f"{tmp_path / 'empty'}: no checkpoint.pt" in done.stderr
    row = next(line for line in done.stdout.splitlines() if line.startswith("| run | 600 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert len(cells) == 8
    share, mean_g, mean_q, bias = cells[2], float(cells[3]), float(cells[4]), float(cells[5])
    assert share.endswith("of 600") and 0 < int(share.split("%")[0]) <= 100
    assert abs((mean_q - mean_g) - bias) <= 0.011  # (each cell rounded to 0.01)
    assert -1.0 <= float(cells[6]) <= 1.0 and float(cells[7]) >= 0.0
