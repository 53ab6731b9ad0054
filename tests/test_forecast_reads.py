"""``benchmarks/forecast_reads.py``: the stationary view rebuilt from a stored observation is the observation the
``stationary`` predictor gives of the same state, and encounters are the states with a near, moving mover (the
script on a real run: tests/test_critic_select.py, which trains one)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from deck_sim.wrappers import DeckSimEnv
from training.envs import env_layout, scene_layout

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("forecast_reads", ROOT / "benchmarks" / "forecast_reads.py")
sys.path.insert(0, str(ROOT / "benchmarks"))
forecast_reads = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(forecast_reads)

NEAR = {"episode__near_steps": 4, "episode__near_obstacles": True, "episode__predicted_near": True}


@pytest.mark.parametrize("options", [NEAR, {**NEAR, "episode__frame": "agent"}, {"episode__predicted_frame": "mover"}])
def test_the_stationary_view_is_what_the_stationary_predictor_observes(options):
    mpc = DeckSimEnv("deck1", episode__predictor="mpc", **options)
    still = DeckSimEnv("deck1", episode__predictor="stationary", **options)
    layout = env_layout(mpc)
    mover_frame = options.get("episode__predicted_frame") == "mover"
    rng = np.random.default_rng(0)
    rows, moved = [], 0.0
    try:
        obs, _ = mpc.reset(seed=11)
        ref, _ = still.reset(seed=11)
        for _ in range(25):  # (the predictor does not act on the physics: both play the same episode)
            rows.append((obs, ref))
            action = rng.uniform(-1.0, 1.0, 2)
            obs, *_, done, cut, _ = mpc.step(action)
            ref, *_ = still.step(action)
            if done or cut:
                break
    finally:
        mpc.close()
        still.close()
    given = np.stack([o for o, _ in rows])
    expected = np.stack([r for _, r in rows])
    sl = layout.slices()
    moved = np.abs(given[:, sl["predicted"]] - expected[:, sl["predicted"]]).max()
    assert moved > 0.1  # (the MPC forecast moves the movers: the view has something to take out)
    np.testing.assert_allclose(forecast_reads.stationary_view(given, layout, mover_frame), expected, atol=1e-5)


@pytest.mark.parametrize(("predictor", "options", "message"), [
    ("mpc", {"episode__predicted_approach": True}, "`predicted_approach` is observed"),
    ("mpc", {"episode__near_steps": 4, "episode__predicted_near": True},
     "`predicted_near` is observed without `dynamic_near`"),
    ("none", {}, "no forecast"),
])
def test_the_stationary_view_refuses_what_it_cannot_rebuild(predictor, options, message):
    layout = scene_layout("deck1", predictor, options)
    with pytest.raises(ValueError, match=message):
        forecast_reads.stationary_view(np.zeros((1, layout.dim), np.float32), layout)


def test_encounters_need_a_near_moving_mover():
    layout = scene_layout("deck1", "mpc", {})
    n, horizon, _ = layout.shapes["predicted"]
    sl = layout.slices()
    flat = np.zeros((4, layout.dim), np.float32)
    now = np.full((4, n, 2), 500.0, np.float32)
    now[:, 0] = (10.0, 0.0)  # mover 0 ten metres away in every row
    forecast = np.repeat(now[:, :, None], horizon, axis=2)
    forecast[1, 0, -1] += (2.0, 0.0)  # row 1: it moves 2 m: an encounter
    forecast[2, 0, -1] += (0.5, 0.0)  # row 2: 0.5 m: too little
    now[3, 0] = (40.0, 0.0)  # row 3: moves 2 m but 40 m away
    forecast[3, 0] = now[3, 0]
    forecast[3, 0, -1] += (2.0, 0.0)
    flat[:, sl["dynamic_obstacles"]] = now.reshape(4, -1)
    flat[:, sl["predicted"]] = forecast.reshape(4, -1)
    assert forecast_reads.encounters(flat, layout, near=30.0, moving=1.0).tolist() == [False, True, False, False]


def test_the_noise_reference_moves_the_forecast_keys_alone():
    env = DeckSimEnv("deck1", episode__predictor="mpc", **NEAR)
    try:
        layout = env_layout(env)
        obs, _ = env.reset(seed=2)
    finally:
        env.close()
    flat = np.stack([obs, obs])
    noisy = forecast_reads.jittered_view(flat, layout, 1.0, np.random.default_rng(0))
    sl = layout.slices()
    moved = {k for k in layout.keys if not np.array_equal(noisy[:, sl[k]], flat[:, sl[k]])}
    assert moved == {"predicted", "predicted_near"}
    assert 0.8 < float(np.std(noisy[:, sl["predicted"]] - flat[:, sl["predicted"]])) < 1.2
