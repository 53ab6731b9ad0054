"""The task with the MPC predictor: its observation's ``predicted`` part is the MPC predictor's output."""

from __future__ import annotations

import math

import numpy as np
import pytest
from dm_control import composer

import deck_sim
from deck_sim.control.mpc_predictor import MPCPredictor
from deck_sim.types import ObstacleTracks

SEED = 5001  # held out from the seeds the predictor was tuned on
STEPS = 14
ACTION = np.array([0.4, 0.1])  # a fixed action: every predictor sees the same episode


def _episode(predictor: str) -> tuple[composer.Environment, list[dict], list[dict]]:
    """Run deck2 for ``STEPS`` control steps with ``predictor``; return (env, observations, infos) per step.

    Element 0 is the state after ``reset``.
    """
    env = deck_sim.load("deck2", seed=SEED, episode__predictor=predictor)
    ts = env.reset()
    observations, infos = [ts.observation], [dict(env.task.last_info)]
    for _ in range(STEPS):
        ts = env.step(ACTION)
        assert not ts.last(), "the test episode must not end early"
        observations.append(ts.observation)
        infos.append(dict(env.task.last_info))
    return env, observations, infos


@pytest.fixture(scope="module")
def mpc_run() -> tuple[composer.Environment, list[dict], list[dict]]:
    """One deck2 episode with ``episode.predictor = "mpc"``."""
    return _episode("mpc")


def test_observation_holds_the_mpc_prediction(mpc_run) -> None:
    env, observations, infos = mpc_run
    assert isinstance(env.task.predictor, MPCPredictor)
    n, horizon = len(env.task.movers), env.task.predictor.horizon
    assert env.observation_spec()["predicted"].shape == (n, horizon, 2)
    for obs, info in zip(observations, infos, strict=True):
        assert info["predictor"] == "mpc"
        order = np.argsort(np.linalg.norm(info["mover_positions"] - info["position"], axis=1), kind="stable")
        np.testing.assert_allclose(obs["predicted"], info["prediction"][order] - info["position"])
        np.testing.assert_allclose(obs["dynamic_obstacles"], info["mover_positions"][order] - info["position"])
    # not the current positions repeated: some mover is predicted to move by metres over the horizon
    last = observations[-1]
    assert np.abs(last["predicted"] - last["dynamic_obstacles"][:, None, :]).max() > 1.0


def test_prediction_equals_a_standalone_predictor_on_the_same_histories(mpc_run) -> None:
    """An MPC predictor of the same settings, fed the histories the task keeps, predicts what the task reports."""
    env, _, infos = mpc_run
    task = env.task
    predictor = MPCPredictor(task.predictor.settings)
    predictor.reset(task._spot_xy, task._kinds)
    positions = np.stack([info["mover_positions"] for info in infos], axis=1)  # (n, T, 2)
    history = task.spec.episode.history
    padded = np.concatenate([np.repeat(positions[:, :1], history - 1, axis=1), positions], axis=1)
    for t, info in enumerate(infos):
        tracks = ObstacleTracks(
            dt=task.spec.episode.control_period, positions=padded[:, t : t + history], kinds=task._kinds
        )
        np.testing.assert_allclose(predictor.predict(tracks).positions, info["prediction"], atol=1e-9)


def test_fallback_counter_is_an_int_and_zero_on_normal_tracks(mpc_run) -> None:
    _, _, infos = mpc_run
    for info in infos:
        assert type(info["predictor_fallbacks"]) is int
        assert info["predictor_fallbacks"] == 0
        assert info["predictor_fallbacks_total"] == 0


@pytest.mark.slow
def test_mpc_differs_from_none_and_from_constant_velocity(mpc_run) -> None:
    _, mpc_obs, mpc_infos = mpc_run
    _, none_obs, none_infos = _episode("none")
    _, cv_obs, cv_infos = _episode("constant_velocity")
    # the predictor only feeds the observation: the episode itself is the same
    for a, b, c in zip(mpc_infos, none_infos, cv_infos, strict=True):
        np.testing.assert_array_equal(a["mover_positions"], b["mover_positions"])
        np.testing.assert_array_equal(a["mover_positions"], c["mover_positions"])
    assert all("predicted" not in obs for obs in none_obs)
    assert all("predicted" in obs for obs in mpc_obs)
    gap = max(np.abs(m["predicted"] - c["predicted"]).max() for m, c in zip(mpc_obs, cv_obs, strict=True))
    assert gap > 0.5, f"MPC and constant velocity agree within {gap:.3f} m on every step"


def test_the_tasks_constant_velocity_equals_the_predictor_on_the_observed_histories() -> None:
    """The task's shortcut for its default predictor gives ``ConstantVelocity.predict``'s numbers bit for bit."""
    from deck_sim.control.prediction import ConstantVelocity

    env = deck_sim.load("deck2", seed=4, episode__predictor="constant_velocity")
    env.reset()
    task = env.task
    first = task.last_info["mover_positions"].copy()
    seen = [first] * task.spec.episode.history  # the task pads the history with the first position
    predictor = ConstantVelocity(horizon=task.spec.episode.horizon)
    rng = np.random.default_rng(1)
    for _ in range(14):
        env.step(rng.uniform(-0.5, 0.5, 2))
        seen = seen[1:] + [task.last_info["mover_positions"].copy()]
        tracks = ObstacleTracks(
            dt=task.spec.episode.control_period,
            positions=np.stack(seen, axis=1),
            kinds=np.zeros(len(first), dtype=int),
        )
        assert np.array_equal(task.last_info["prediction"], predictor.predict(tracks).positions)


def test_the_lookahead_reward_is_the_same_whatever_the_agent_observes_and_reads_the_forecast() -> None:
    """``reward.lookahead_steps``: r2 reads the movers' closest approach along the MPC forecast, the same forecast
    whether the agent observes it, observes another or none; the observed clearance stays the one now."""

    def run(predictor: str, lookahead: int) -> tuple[list[float], list[float]]:
        env = deck_sim.load("deck1", seed=3, episode__predictor=predictor, reward__lookahead_steps=lookahead)
        env.reset()
        r2, clearance = [], []
        for i in range(60):
            ts = env.step(np.array([0.6, 0.1]))
            r2.append(env.task.last_info["reward_terms"]["r2"])
            clearance.append(env.task.last_info["min_clearance"])
            if ts.last() or i == 29:  # (at least two episodes: the look-ahead's predictor starts each afresh)
                env.reset()
        return r2, clearance

    looked, seen = run("mpc", 6)
    assert run("none", 6) == (looked, seen) and run("constant_velocity", 6) == (looked, seen)
    paper, seen_paper = run("mpc", 0)
    assert seen_paper == seen  # the same episode: the reward changes nothing the agent does here
    assert looked != paper and sum(looked) < sum(paper)  # encounters ahead are penalised before they come


def test_the_closest_approach_key_is_read_from_the_forecast_the_agent_observes_in_either_frame() -> None:
    """``episode.predicted_approach``: each mover's closest approach on the MPC forecast the observation holds, the
    same in the world's axes and the agent's; refused without a predictor."""
    from deck_sim.scenes import SceneSpecError
    from deck_sim.tasks.observation import closest_approach

    env = deck_sim.load("deck1", seed=3, episode__predictor="mpc", episode__predicted_approach=True)
    world = [env.reset().observation] + [env.step(np.array([0.6, 0.0])).observation for _ in range(20)]
    for obs in world:
        assert obs["predicted_approach"].shape == (5, 2)
        np.testing.assert_allclose(
            obs["predicted_approach"],
            closest_approach(obs["dynamic_obstacles"], obs["predicted"], obs["velocity"], 0.5), rtol=1e-12,
        )
    assert any(obs["predicted_approach"][:, 0].max() > 0 for obs in world)  # (some mover comes nearer later)
    ego = deck_sim.load("deck1", seed=3, episode__predictor="mpc", episode__predicted_approach=True,
                        episode__frame="agent")
    obs = ego.reset().observation
    np.testing.assert_allclose(obs["predicted_approach"], world[0]["predicted_approach"], rtol=1e-9, atol=1e-9)
    with pytest.raises(SceneSpecError, match=r"predicted_approach: is read from the forecast: it needs a predictor"):
        deck_sim.load("deck1", seed=3, episode__predictor="none", episode__predicted_approach=True)


def test_the_near_forecast_is_the_observed_forecast_at_the_near_fields_scale_and_no_agent_without_one_sees_it():
    """``episode.predicted_near``: each mover's nearest point carried along its MPC forecast and clipped to the near
    field, as the observation's own ``dynamic_nearest``, ``predicted`` and ``dynamic_obstacles`` give it; with a
    forecast of standing movers it repeats ``dynamic_near``; the same in the agent's axes turned; refused without
    a predictor; a DDPG run's observation leaves it out."""
    from deck_sim.geometry import clip_length, world_to_agent
    from deck_sim.scenes import SceneSpecError

    near = {"episode__near_steps": 4, "episode__near_obstacles": True, "episode__predicted_near": True}
    env = deck_sim.load("deck1", seed=3, episode__predictor="mpc", episode__obstacle_shape=True, **near)
    world = [env.reset().observation] + [env.step(np.array([0.6, 0.0])).observation for _ in range(12)]
    field = 4 * 3.0  # deck 1's reach, 3 m
    for obs in world:
        assert obs["predicted_near"].shape == (5, 10, 2)
        carried = obs["dynamic_nearest"][:, None] + obs["predicted"] - obs["dynamic_obstacles"][:, None]
        np.testing.assert_allclose(obs["predicted_near"], clip_length(carried, field), rtol=1e-9, atol=1e-9)
    assert any(np.abs(o["predicted_near"] - o["dynamic_near"][:, None]).max() > 0.1 for o in world)  # (they move)
    still = deck_sim.load("deck1", seed=3, episode__predictor="stationary", **near)
    obs = still.reset().observation
    np.testing.assert_allclose(obs["predicted_near"], np.repeat(obs["dynamic_near"][:, None], 10, 1), atol=1e-9)
    ego = deck_sim.load("deck1", seed=3, episode__predictor="mpc", episode__frame="agent", **near)
    obs = ego.reset().observation
    yaw = math.atan2(obs["heading"][1], obs["heading"][0])
    np.testing.assert_allclose(obs["predicted_near"], world_to_agent(world[0]["predicted_near"], yaw), atol=1e-9)
    with pytest.raises(SceneSpecError, match=r"predicted_near: is read from the forecast: it needs a predictor"):
        deck_sim.load("deck1", seed=3, episode__predictor="none", **near)
