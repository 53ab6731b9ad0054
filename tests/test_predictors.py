"""The simple predictors (none, constant velocity, stationary, oracle) and the task's prediction plumbing."""

import numpy as np
import pytest

import deck_sim
from deck_sim.control.prediction import (
    ConstantVelocity,
    NoPrediction,
    Oracle,
    PredictionInputError,
    Stationary,
    make_predictor,
)
from deck_sim.types import ObstacleTracks


def _straight(n=3, h=10, dt=0.5, v=(1.5, -0.5)):
    t = np.arange(h) * dt
    pos = np.stack([np.stack([i + v[0] * t, 2 * i + v[1] * t], axis=1) for i in range(n)])
    return ObstacleTracks(dt=dt, positions=pos, kinds=np.zeros(n, dtype=int))


def test_constant_velocity_is_exact_on_a_straight_track():
    tracks = _straight()
    pred = ConstantVelocity(horizon=6).predict(tracks)
    steps = np.arange(1, 7) * 0.5
    expected = tracks.current[:, None, :] + steps[None, :, None] * np.array([1.5, -0.5])
    np.testing.assert_allclose(pred.positions, expected, atol=1e-12)
    assert pred.n_fallbacks == 0


def test_none_predicts_nothing_and_oracle_returns_the_future():
    tracks = _straight()
    assert NoPrediction().predict(tracks).positions.shape == (3, 0, 2)
    future = np.random.default_rng(0).normal(size=(3, 4, 2))
    out = Oracle(horizon=4).predict(ObstacleTracks(0.5, tracks.positions, tracks.kinds, future))
    np.testing.assert_array_equal(out.positions, future)
    with pytest.raises(PredictionInputError, match="needs tracks.future"):
        Oracle(horizon=4).predict(tracks)


def test_stationary_holds_every_obstacle_where_it_is_and_the_task_observes_that():
    tracks = _straight()
    pred = Stationary(horizon=5).predict(tracks)
    np.testing.assert_array_equal(pred.positions, np.repeat(tracks.current[:, None, :], 5, axis=1))
    assert make_predictor("stationary", 5, 0.5).name == "stationary"
    env = deck_sim.load("deck1", seed=3, episode__predictor="stationary")
    obs = env.reset().observation
    rel = obs["dynamic_obstacles"]  # (movers' positions now, relative to the agent, as every predicted row)
    np.testing.assert_allclose(obs["predicted"], np.repeat(rel[:, None, :], obs["predicted"].shape[1], axis=1),
                               atol=1e-5)


@pytest.mark.parametrize(
    "positions, message",
    [
        (np.full((2, 5, 2), np.nan), "NaN or infinite values for obstacle"),
        (np.zeros((2, 0, 2)), "history too short"),
        (np.zeros((2, 5)), "shape"),
    ],
)
def test_malformed_histories_are_refused(positions, message):
    tracks = ObstacleTracks(dt=0.5, positions=positions, kinds=np.zeros(2, dtype=int))
    with pytest.raises(PredictionInputError, match=message):
        ConstantVelocity().predict(tracks)


@pytest.mark.parametrize("dt", [0.0, -0.5, float("nan"), None, "0.5"])
def test_a_bad_sampling_period_is_refused(dt):
    tracks = ObstacleTracks(dt=dt, positions=np.zeros((2, 5, 2)), kinds=np.zeros(2, dtype=int))
    with pytest.raises(PredictionInputError, match="dt must be a positive number of seconds"):
        ConstantVelocity().predict(tracks)


def test_unknown_predictor_is_named():
    with pytest.raises(ValueError, match="unknown predictor 'psychic'"):
        make_predictor("psychic", 10, 0.5)


def test_task_observation_holds_the_predictors_output():
    env = deck_sim.load("deck1", seed=4, episode__predictor="constant_velocity")
    env.reset()
    for _ in range(6):
        ts = env.step(np.array([0.3, 0.0]))
    task = env.task
    info = task.last_info
    order = np.argsort(np.linalg.norm(info["mover_positions"] - info["position"], axis=1), kind="stable")
    np.testing.assert_allclose(ts.observation["predicted"], info["prediction"][order] - info["position"])
    np.testing.assert_allclose(
        ts.observation["dynamic_obstacles"], info["mover_positions"][order] - info["position"]
    )


def test_oracle_sees_the_true_future_without_disturbing_the_episode():
    kwargs = dict(seed=11, movers__yield_to_agent=False, episode__horizon=4)
    oracle = deck_sim.load("deck2", episode__predictor="oracle", **kwargs)
    plain = deck_sim.load("deck2", episode__predictor="none", **kwargs)
    oracle.reset()
    plain.reset()
    predicted = []
    truth = []
    for _ in range(8):
        a = np.array([0.0, 0.0])  # the agent brakes where it stands, as the oracle's copy assumes
        oracle.step(a)
        plain.step(a)
        predicted.append(oracle.task.last_info["prediction"].copy())
        truth.append(plain.task.last_info["mover_positions"].copy())
        # simulating ahead must not change the episode itself
        np.testing.assert_array_equal(oracle.task.last_info["mover_positions"], truth[-1])
    # the prediction made at step k for step k + j equals what happened
    for k in range(len(truth) - 4):
        for j in range(1, 5):
            np.testing.assert_allclose(predicted[k][:, j - 1], truth[k + j], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 5])
def test_the_episode_does_not_depend_on_the_predictor(seed):
    # movers that yield to the agent keep timers (how long they waited on it, when they last gave up); simulating
    # ahead must leave those as it found them, or the oracle would change the episode it predicts
    from deck_sim.policies import ScriptedPolicy

    oracle = deck_sim.load("deck2", seed=seed, episode__predictor="oracle")
    plain = deck_sim.load("deck2", seed=seed, episode__predictor="none")
    policy = ScriptedPolicy(oracle)
    ts = oracle.reset()
    plain.reset()
    policy.reset()
    for _ in range(40):
        action = policy.act(ts.observation)
        ts = oracle.step(action)
        plain.step(action)
        np.testing.assert_array_equal(oracle.task.last_info["mover_positions"], plain.task.last_info["mover_positions"])
        if ts.last():
            break


def test_none_predictor_has_no_predicted_observation():
    env = deck_sim.load("deck1", seed=0, episode__predictor="none")
    assert "predicted" not in env.observation_spec()


def test_the_control_library_imports_without_mujoco():
    import subprocess
    import sys

    code = ("import sys; import deck_sim.control.prediction, deck_sim.control.planners, deck_sim.control.tracking, "
            "deck_sim.control.mpc_predictor; "
            "print(sorted(m for m in ('mujoco', 'dm_control') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
