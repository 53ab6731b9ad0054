"""Hindsight goals and n-step returns (``training.her``): a relabelled transition is what the task would have paid
for that target, the buffer keeps each episode's rows through wrap-around and checkpoints, and runs with them
resume exactly."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from deck_sim.scenes import load_scene
from deck_sim.tasks import rewards
from tests.conftest import short_config
from tests.training_runs import assert_same_run
from training.buffers import EpisodeMarks, ReplayBuffer
from training.config import ConfigError
from training.envs import env_layout, make_env
from training.her import GoalGeometry, GoalLayoutError, HindsightSampler, relabel
from training.loop import Trainer


def _episode(frame: str, steps: int = 40, seed: int = 3):
    """Flat observations, rewards and infos of a seeded random walk on deck 1 (``episode.frame`` = ``frame``)."""
    env = make_env("deck1", "none", episode__frame=frame, episode__near_steps=4)
    layout = env_layout(env)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = {"obs": [], "next_obs": [], "reward": [], "info": []}
    for _ in range(steps):
        nxt, reward, terminated, truncated, info = env.step(np.clip([0.9, 0.0] + rng.normal(0, 0.4, 2), -1, 1))
        out["obs"].append(obs)
        out["next_obs"].append(nxt)
        out["reward"].append(reward)
        out["info"].append(info)
        obs = nxt
        if terminated or truncated:
            break
    env.close()
    spec = load_scene("deck1", episode__frame=frame, episode__near_steps=4)
    return GoalGeometry.of(spec, layout.shapes), {k: np.asarray(v) if k != "info" else v for k, v in out.items()}


@pytest.mark.parametrize("frame", ["world", "agent"])
def test_relabelling_with_the_episodes_own_target_changes_nothing(frame):
    geo, ep = _episode(frame)
    obs, nxt = ep["obs"].astype(np.float32), ep["next_obs"].astype(np.float32)
    n = len(obs)
    target = ep["obs"][0][geo.position] + _world(geo, ep["obs"][:1])[0]  # where the target lies
    reached = np.array([float(i["reached_goal"]) for i in ep["info"]])
    failed = np.array([float(i["collision"] is not None or i["left_surface"]) for i in ep["info"]])
    o, no, r, term = relabel(geo, obs, nxt, ep["reward"].astype(np.float32), reached, failed, np.tile(target, (n, 1)))
    np.testing.assert_allclose(o, obs, atol=2e-4)
    np.testing.assert_allclose(no, nxt, atol=2e-4)
    np.testing.assert_allclose(r, ep["reward"], atol=1e-3)
    np.testing.assert_array_equal(term, np.maximum(reached, failed))


def _world(geo: GoalGeometry, obs: np.ndarray) -> np.ndarray:
    """The target vectors of ``obs`` in the world's axes."""
    t = obs[:, geo.target].astype(np.float64)
    if not geo.agent_frame:
        return t
    c, s = obs[:, geo.heading.start], obs[:, geo.heading.start + 1]
    return np.stack([t[:, 0] * c - t[:, 1] * s, t[:, 0] * s + t[:, 1] * c], axis=1)


@pytest.mark.parametrize("frame", ["world", "agent"])
def test_a_hindsight_target_is_paid_as_the_task_pays_a_target(frame):
    geo, ep = _episode(frame)
    obs, nxt = ep["obs"].astype(np.float32), ep["next_obs"].astype(np.float32)
    n = len(obs)
    pos = np.array([i["position"] for i in ep["info"]])  # the agent after each step
    goal = pos[n // 2]
    reached = np.array([float(i["reached_goal"]) for i in ep["info"]])
    failed = np.zeros(n)
    o, no, r, term = relabel(geo, obs, nxt, ep["reward"].astype(np.float32), reached, failed, np.tile(goal, (n, 1)))
    spec = load_scene("deck1")
    before = np.r_[np.hypot(*(goal - np.asarray(ep["obs"][0][geo.position], float))), np.hypot(*(goal - pos[:-1]).T)]
    after = np.hypot(*(goal - pos).T)
    for k in range(n):
        terms = [i["reward_terms"] for i in ep["info"]][k]
        r1 = rewards.attraction(before[k], after[k], spec.reward.attraction_min, spec.reward.attraction_max,
                                spec.reward.progress_deadband)
        hit = after[k] <= spec.agent.goal_radius
        expected = r1 + terms["r2"] + terms["r3"] + (spec.reward.goal if hit else 0.0)
        assert r[k] == pytest.approx(expected, abs=2e-3), k
        assert term[k] == float(hit)
    assert term[n // 2] == 1.0 and r[n // 2] > spec.reward.goal - spec.reward.attraction_max - 3.1
    assert np.hypot(*geo.relative(goal[None], o[n // 2 : n // 2 + 1])[0]) == pytest.approx(before[n // 2], abs=1e-3)


def test_an_observation_with_a_route_cannot_take_hindsight_targets(tmp_path):
    env = make_env("deck1", "none", episode__route_steps=3)
    layout = env_layout(env)
    env.close()
    with pytest.raises(GoalLayoutError, match="route"):
        GoalGeometry.of(load_scene("deck1", episode__route_steps=3), layout.shapes)
    cfg = short_config(her_ratio=0.5, demo_episodes=0, pretrain_updates=0, bc_weight=0.0, expert_relabel=False,
                       scene_overrides={"episode__route_steps": 3})
    with pytest.raises(ConfigError, match="her_ratio: hindsight goals: .*route"):
        Trainer(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(("field", "value"), [("her_ratio", 1.5), ("her_ratio", -0.1), ("n_step", 0), ("n_step", True)])
def test_bad_values_are_named(field, value):
    with pytest.raises(ConfigError, match=field):
        short_config(**{field: value})


def _marks(ep, step, end, reached=0.0, failed=0.0):
    one = lambda v: np.array([v])  # noqa: E731
    return EpisodeMarks(one(ep), one(step), one(reached), one(failed), one(1.0), one(end))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 9), min_size=1, max_size=12), st.integers(3, 30))
def test_episode_rows_survive_wraparound_and_checkpoints(lengths, capacity):
    buf = ReplayBuffer(capacity, 1, 1, track_episodes=True)
    written = []  # (episode, step) of every row written, in order
    for ep, length in enumerate(lengths):
        for t in range(length):
            v = np.array([[ep * 100.0 + t]], dtype=np.float32)
            buf.add(v, v, np.zeros(1), v, np.zeros(1), marks=_marks(ep, t, float(t == length - 1)))
            written.append((ep, t))
    alive = written[-min(capacity, len(written)):]
    for ep, lst in buf.episode_rows.items():
        for t, row in enumerate(lst):
            if row >= 0:
                assert buf.obs[row, 0] == ep * 100 + t and (ep, t) in alive
    assert {(e, t) for e, lst in buf.episode_rows.items() for t, r in enumerate(lst) if r >= 0} == set(alive)
    again = ReplayBuffer(capacity, 1, 1, track_episodes=True)
    again.load_state_dict(buf.state_dict())
    assert again.episode_rows == buf.episode_rows


def test_n_step_returns_sum_the_episodes_next_rewards_and_stop_at_its_end():
    gamma = 0.9
    buf = ReplayBuffer(50, 1, 1, track_episodes=True)
    rewards_ = [1.0, 2.0, 4.0, 8.0]
    for t, r in enumerate(rewards_):  # one episode, terminated on its last step
        last = t == len(rewards_) - 1
        o = np.array([[float(t)]], dtype=np.float32)
        buf.add(o, o, np.array([r]), o + 1, np.array([float(last)]), marks=_marks(7, t, float(last)))
    sampler = HindsightSampler(None, 0.0, 3, gamma)
    batch = sampler.batch(buf, np.arange(4), np.random.default_rng(0))
    expected = [1 + 0.9 * 2 + 0.81 * 4, 2 + 0.9 * 4 + 0.81 * 8, 4 + 0.9 * 8, 8.0]
    np.testing.assert_allclose(batch.reward.numpy(), expected, rtol=1e-6)
    np.testing.assert_allclose(batch.discount.numpy(), [0.9**3, 0.9**3, 0.9**2, 0.9], rtol=1e-6)
    np.testing.assert_array_equal(batch.next_obs.numpy()[:, 0], [3, 4, 4, 4])
    np.testing.assert_array_equal(batch.terminated.numpy(), [0, 1, 1, 1])
    one = HindsightSampler(None, 0.0, 1, gamma).batch(buf, np.arange(4), np.random.default_rng(0))
    assert one.discount is None
    np.testing.assert_array_equal(one.reward.numpy(), rewards_)


def test_the_td_target_uses_the_batches_own_discount():
    from training.ddpg import DDPGAgent

    cfg = short_config(gamma=0.5, target_noise=0.0)
    agent = DDPGAgent(3, 2, cfg)
    buf = ReplayBuffer(10, 3, 2)
    buf.add(np.ones((2, 3)), np.zeros((2, 2)), np.array([1.0, 1.0]), np.ones((2, 3)), np.zeros(2))
    plain = buf.sample(2, np.random.default_rng(0))
    q = (agent.td_target(plain) - cfg.reward_scale) / 0.5  # y = reward_scale * 1 + gamma * q
    y = agent.td_target(plain._replace(discount=torch.tensor([0.25, 0.0])))
    np.testing.assert_allclose(y.numpy(), (cfg.reward_scale + torch.tensor([0.25, 0.0]) * q).numpy(), rtol=1e-5)


def _reward_only(**fields):
    base = dict(demo_episodes=0, pretrain_updates=0, bc_weight=0.0, expert_relabel=False, her_ratio=0.8, n_step=3)
    return short_config(**{**base, **fields})


@pytest.mark.slow
def test_a_hindsight_n_step_run_learns_from_the_reward_alone_and_resumes_exactly(tmp_path):
    from deck_sim.policies.regimes import config_regime

    cfg = _reward_only()
    assert config_regime(cfg.to_dict()) == "reward"
    whole = Trainer(cfg, tmp_path / "whole", progress=False)
    whole.train()
    assert whole.buffer.track_episodes and whole.buffer.episode_rows
    first = Trainer(cfg, tmp_path / "broken", progress=False)
    first.train(stop_at=70)
    resumed = Trainer(cfg, tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
    assert resumed.buffer.episode_rows == whole.buffer.episode_rows


def test_configs_and_actor_records_name_their_regime(tmp_path):
    import json

    from training.baseline_config import baseline_config
    from training.config import TrainConfig, make_config

    reward = _reward_only()
    assert reward.regime == "reward" and make_config("tuned").regime == "oracle-teacher"
    reward.save(tmp_path / "config.json")
    assert json.loads((tmp_path / "config.json").read_text())["regime"] == "reward"
    assert TrainConfig.load(tmp_path / "config.json") == reward
    with pytest.raises(ConfigError, match="regime: the config says 'reward', but its fields make 'oracle-teacher'"):
        TrainConfig.from_dict({**make_config("tuned").to_dict(), "regime": "reward"})
    dqn = baseline_config("dqn")
    dqn.save(tmp_path / "dqn.json")
    assert json.loads((tmp_path / "dqn.json").read_text())["regime"] == "reward"
    assert type(dqn).from_dict(json.loads((tmp_path / "dqn.json").read_text())) == dqn
    with pytest.raises(ConfigError, match="regime"):
        type(dqn).from_dict({**dqn.to_dict(), "regime": "planner"})
