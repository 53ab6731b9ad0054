"""The DDPG agent's parts by hand (TD target, losses, soft update, replay), and training runs on real scenes:
determinism, exact resume, clear errors on bad checkpoints, learning beats random on a simple deck."""

from __future__ import annotations

import copy
import csv
import json

import numpy as np
import pytest
import torch
from conftest import NEAR
from conftest import short_config as _short

from training.buffers import ReplayBuffer
from training.config import ConfigError, TrainConfig, make_config, train_episode_seed
from training.ddpg import DDPGAgent, soft_update
from training.envs import FAR, ObservationLayout
from training.loop import CheckpointError, Trainer, load_checkpoint, shipped_actor


def _set_linear(layer: torch.nn.Linear, weight, bias) -> None:  # noqa: ANN001
    with torch.no_grad():
        layer.weight.copy_(torch.tensor(weight, dtype=torch.float32))
        layer.bias.copy_(torch.tensor(bias, dtype=torch.float32))


def _tiny_agent(**fields) -> DDPGAgent:  # noqa: ANN003
    """obs 2, action 1, one hidden unit: every network's output is computable by hand."""
    cfg = TrainConfig(hidden=(1,), gamma=0.9, tau=0.5, batch_size=2, **fields)
    agent = DDPGAgent(2, 1, cfg)
    for nets in ((agent.actor, agent.actor_target),):
        for net in nets:
            _set_linear(net.net[0], [[1.0, -1.0]], [0.0])  # h = relu(o0 - o1)
            _set_linear(net.net[2], [[0.5]], [0.0])  # a = tanh(0.5 h)
    for net in (agent.critic, agent.critic_target):
        for head in net.heads:
            _set_linear(head[0], [[1.0, 1.0, 2.0]], [0.0])  # h = relu(o0 + o1 + 2 a)
            _set_linear(head[2], [[3.0]], [1.0])  # q = 3 h + 1
    return agent


def _batch(obs, action, reward, next_obs, terminated, demo=None):  # noqa: ANN001, ANN202
    from training.buffers import Batch

    t = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
    demo = t(demo or [0.0] * len(reward))
    return Batch(t(obs), t(action), t(reward), t(next_obs), t(terminated), demo, t(action), demo)


def test_td_target_and_critic_loss_equal_a_hand_computed_case():
    agent = _tiny_agent()
    batch = _batch([[1.0, 0.0], [0.5, 0.5]], [[0.5], [-1.0]], [1.0, -2.0], [[2.0, 1.0], [0.0, 3.0]], [0.0, 1.0])
    # transition 0: mu'(s') = tanh(0.5 * relu(2 - 1)) = tanh(0.5); Q' = 3 relu(3 + 2 tanh 0.5) + 1
    q_next0 = 3.0 * (3.0 + 2.0 * np.tanh(0.5)) + 1.0
    y0 = 1.0 + 0.9 * q_next0
    y1 = -2.0  # terminated: no bootstrap
    np.testing.assert_allclose(agent.td_target(batch).numpy(), [y0, y1], rtol=1e-6)
    q0 = 3.0 * (1.0 + 0.0 + 2.0 * 0.5) + 1.0  # Q(s, a) of the stored actions
    q1 = 3.0 * max(0.0, 0.5 + 0.5 - 2.0) + 1.0
    stats = agent.update(batch)
    np.testing.assert_allclose(stats["critic_loss"], ((q0 - y0) ** 2 + (q1 - y1) ** 2) / 2, rtol=1e-6)
    np.testing.assert_allclose(stats["q"], (q0 + q1) / 2, rtol=1e-6)


def test_actor_loss_and_the_twin_critics_minimum_by_hand():
    agent = _tiny_agent(twin_critics=True)
    with torch.no_grad():  # second target head: q = 3 h - 4, always 5 below the first
        agent.critic_target.heads[1][2].bias.fill_(-4.0)
        agent.critic.heads[1][2].bias.fill_(-4.0)
    batch = _batch([[1.0, 0.0]], [[0.5]], [0.0], [[2.0, 1.0]], [0.0])
    y = 0.9 * (3.0 * (3.0 + 2.0 * np.tanh(0.5)) - 4.0)
    np.testing.assert_allclose(agent.td_target(batch).numpy(), [y], rtol=1e-6)
    before = copy.deepcopy(agent.critic)
    stats = agent.update(batch)
    # the actor loss uses the critic after its update: -Q1(s, mu(s)), mu(s) = tanh(0.5)
    expected = -_q1_by_hand(agent, np.array([1.0, 0.0]), np.tanh(0.5))
    np.testing.assert_allclose(stats["actor_loss"], expected, rtol=1e-5)
    assert not torch.equal(before.heads[0][0].weight, agent.critic.heads[0][0].weight)


def _q1_by_hand(agent: DDPGAgent, obs: np.ndarray, action: float) -> float:
    """Q1 of the agent's (already updated) critic at one state and action, evaluated by hand from its weights."""
    head = agent.critic.heads[0]
    w0, b0 = head[0].weight.detach().numpy(), head[0].bias.detach().numpy()
    w1, b1 = head[2].weight.detach().numpy(), head[2].bias.detach().numpy()
    h = np.maximum(w0 @ np.array([*obs, action]) + b0, 0.0)
    return float((w1 @ h + b1)[0])


def test_cloning_term_and_q_normalisation_by_hand():
    from training.buffers import Batch

    agent = _tiny_agent(bc_weight=2.0, q_filter=False, bc_normalise_q=True)
    t = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
    # two states; only the first has a label (the planner's action -0.5); mu(s0) = tanh(0.5), mu(s1) = tanh(0)
    batch = Batch(
        t([[1.0, 0.0], [0.0, 1.0]]),
        t([[0.0], [0.0]]),
        t([0.0, 0.0]),
        t([[0.0, 0.0], [0.0, 0.0]]),
        t([1.0, 1.0]),
        t([0.0, 0.0]),
        t([[-0.5], [0.0]]),
        t([1.0, 0.0]),
    )
    stats = agent.update(batch)
    np.testing.assert_allclose(stats["bc_loss"], (np.tanh(0.5) + 0.5) ** 2, rtol=1e-6)
    np.testing.assert_allclose(stats["actor_loss"], -1.0, rtol=1e-6)  # every Q > 0: -mean Q / mean |Q|
    assert stats["bc_share"] == 1.0
    with_filter = _tiny_agent(bc_weight=2.0, q_filter=True)
    assert with_filter.update(batch)["bc_share"] == 0.0  # the critic rates tanh(0.5) above -0.5: not cloned
    # both labelled; the planner's -0.5 is slow (|a| < 0.9) and weighs 3 times, its 1.0 on s1 once
    both = batch._replace(expert_action=t([[-0.5], [1.0]]), labelled=t([1.0, 1.0]))
    slow = _tiny_agent(bc_weight=2.0, q_filter=False, bc_slow_weight=3.0)
    want = (3.0 * (np.tanh(0.5) + 0.5) ** 2 + 1.0 * (0.0 - 1.0) ** 2) / 4.0
    np.testing.assert_allclose(slow.update(both)["bc_loss"], want, rtol=1e-6)
    plain = _tiny_agent(bc_weight=2.0, q_filter=False)
    np.testing.assert_allclose(plain.update(both)["bc_loss"], ((np.tanh(0.5) + 0.5) ** 2 + 1.0) / 2.0, rtol=1e-6)


def test_soft_update_is_exact():
    torch.manual_seed(0)
    source, target = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    pairs = zip(source.parameters(), target.parameters(), strict=True)
    expected = [0.25 * s.detach() + 0.75 * t.detach() for s, t in pairs]
    soft_update(target, source, 0.25)
    for e, t in zip(expected, target.parameters(), strict=True):
        assert torch.equal(e, t.detach())
    soft_update(target, source, 1.0)
    for s, t in zip(source.parameters(), target.parameters(), strict=True):
        assert torch.equal(s, t)


def test_buffer_rings_keeps_demonstrations_and_samples_typed_batches():
    buf = ReplayBuffer(capacity=6, obs_dim=2, act_dim=1)
    row = lambda v, n: np.full((n, 2), v, dtype=np.float32)  # noqa: E731
    buf.add_demos(row(-1, 2), np.full((2, 1), -1.0), np.full(2, -1.0), row(-1, 2), np.ones(2))
    for v in range(6):  # 6 agent rows into 4 free places: the two oldest are overwritten
        buf.add(row(v, 1), np.full((1, 1), v), np.full(1, v), row(v, 1), np.zeros(1))
    assert (buf.size, buf.n_demo, buf.n_agent) == (6, 2, 4)
    assert sorted(buf.reward[2:].tolist()) == [2.0, 3.0, 4.0, 5.0]
    assert buf.reward[:2].tolist() == [-1.0, -1.0]
    rng = np.random.default_rng(0)
    b = buf.sample(8, rng, demo_fraction=0.25)
    assert b.obs.dtype == torch.float32 and b.obs.shape == (8, 2) and b.action.shape == (8, 1)
    assert b.demo.tolist() == [1.0, 1.0] + [0.0] * 6
    assert torch.all(b.reward[:2] == -1.0) and torch.all(b.reward[2:] >= 2.0)
    assert torch.all(b.terminated[:2] == 1.0)
    with pytest.raises(RuntimeError, match="before the agent"):
        buf.add_demos(row(0, 1), np.zeros((1, 1)), np.zeros(1), row(0, 1), np.zeros(1))
    with pytest.raises(RuntimeError, match="empty"):
        ReplayBuffer(3, 2, 1).sample(1, rng)


def test_observation_layout_selects_and_pads():
    full = ObservationLayout({"target": (2,), "dynamic_obstacles": (3, 2), "predicted": (3, 2, 2), "heading": (2,)})
    small = ObservationLayout({"target": (2,), "dynamic_obstacles": (1, 2), "predicted": (1, 2, 2), "heading": (2,)})
    flat = np.arange(small.dim, dtype=np.float32)
    padded = small.pad_to(flat, full)
    assert padded.shape == (full.dim,)
    sl = full.slices()
    assert padded[sl["target"]].tolist() == [0, 1]
    assert padded[sl["dynamic_obstacles"]].tolist() == [2, 3] + [FAR] * 4
    assert padded[sl["predicted"]].tolist() == [4, 5, 6, 7] + [FAR] * 8
    assert padded[sl["heading"]].tolist() == [8, 9]
    nopred = full.without(("predicted",))
    assert full.select(padded[None], nopred).shape == (1, nopred.dim)
    # the movers' sizes pad with 0; in the mover frame so do the predicted displacements
    full_s = ObservationLayout({"dynamic_size": (3, 2), "predicted": (3, 1, 2)})
    small_s = ObservationLayout({"dynamic_size": (1, 2), "predicted": (1, 1, 2)})
    out = small_s.pad_to(np.ones(small_s.dim, dtype=np.float32), full_s, {"predicted": 0.0})
    assert out.tolist() == [1, 1] + [0] * 4 + [1, 1] + [0] * 4


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="algo"):
        make_config("tuned", algo="ppo")
    with pytest.raises(ConfigError, match="gamma"):
        make_config("paper", gamma=1.5)
    with pytest.raises(ConfigError, match="unknown training config field"):
        make_config("paper", learning_rate=1e-3)
    with pytest.raises(ConfigError, match="preset"):
        make_config("fast")
    assert train_episode_seed(0, 0, 0) >= 1_000_000  # training episodes never use the evaluation seeds


# -- runs on real scenes -------------------------------------------------------------------------------------------


def _rows(path):  # noqa: ANN001, ANN202
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in ("wall_s", "sps")} for r in csv.DictReader(f)]


def _actor_arrays(run_dir):  # noqa: ANN001, ANN202
    with np.load(run_dir / "actor.npz", allow_pickle=False) as d:
        return {k: d[k] for k in d.files if k != "meta"}


def _assert_same_run(a: Trainer, b: Trainer) -> None:
    """Same logged losses and statistics, same exported actor, same replay content (actions and observations)."""
    assert _rows(a.run_dir / "progress.csv") == _rows(b.run_dir / "progress.csv")
    for k, v in _actor_arrays(a.run_dir).items():
        np.testing.assert_array_equal(v, _actor_arrays(b.run_dir)[k], err_msg=k)
    for name in ("action", "obs"):
        rows_a, rows_b = getattr(a.buffer, name)[: a.buffer.size], getattr(b.buffer, name)[: b.buffer.size]
        np.testing.assert_array_equal(rows_a, rows_b, err_msg=name)


def test_two_seeded_runs_give_identical_losses_and_actions(tmp_path):
    """...and it makes no difference whether the environments step in a worker process or inline."""
    a = Trainer(_short(env_worker=True), tmp_path / "a", progress=False)
    a.train()
    b = Trainer(_short(env_worker=False), tmp_path / "b", progress=False)
    b.train()
    _assert_same_run(a, b)


@pytest.mark.parametrize("fields", [{}, {"bc_weight_final": 2.0, "bc_slow_weight": 3.0}], ids=["tuned", "schedule"])
def test_a_stopped_and_resumed_run_equals_an_unbroken_one(tmp_path, fields):
    """...also with a falling cloning weight, which the resumed run must take up at the step it stopped at."""
    whole = Trainer(_short(**fields), tmp_path / "whole", progress=False)
    whole.train()
    first = Trainer(_short(**fields), tmp_path / "broken", progress=False)
    out = first.train(stop_at=70)  # mid-episode in both environments
    assert out["step"] == 70 and not (tmp_path / "broken" / "actor.npz").exists()
    assert any(len(s.actions) > 0 for s in first.slots)
    resumed = Trainer(_short(**fields), tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    _assert_same_run(whole, resumed)


def test_a_checkpoint_from_before_a_new_field_resumes_with_its_default(tmp_path):
    run = tmp_path / "run"
    cfg = _short(total_steps=60, demo_episodes=0, pretrain_updates=0)
    Trainer(cfg, run, progress=False).train(stop_at=40)
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    for key in ("bc_slow_weight", "bc_slow_below", "bc_weight_final", "bc_decay"):  # added after older runs
        del state["config"][key]
    torch.save(state, run / "checkpoint.pt")
    out = Trainer(cfg, run, resume=True, progress=False).train()
    assert out["step"] == 60


def test_bad_checkpoints_give_clear_errors(tmp_path):
    run = tmp_path / "run"
    Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, progress=False).train()
    with pytest.raises(CheckpointError, match="already holds a run"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, progress=False)
    with pytest.raises(CheckpointError, match="another configuration.*hidden"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0, hidden=(16,)), run, resume=True)
    data = (run / "checkpoint.pt").read_bytes()
    (run / "checkpoint.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="checkpoint.pt: not a readable checkpoint"):
        load_checkpoint(run / "checkpoint.pt")
    (run / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        Trainer(_short(total_steps=40, demo_episodes=0, pretrain_updates=0), run, resume=True)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        Trainer(_short(), tmp_path / "empty", resume=True)
    assert json.loads((run / "config.json").read_text())["hidden"] == [32, 32]  # what was written survives


def test_a_short_run_on_an_empty_deck_beats_random(tmp_path):
    import deck_sim
    from deck_sim.metrics import summarize
    from deck_sim.policies import LearnedPolicy, RandomPolicy
    from deck_sim.rollout import run_episode

    cfg = _short(
        scene_overrides=NEAR,
        total_steps=1200,
        demo_episodes=4,
        pretrain_updates=300,
        hidden=(64, 64),
        batch_size=64,
        eval_every=0,
        eval_episodes=10,
        noise_sigma=0.2,
    )
    out = Trainer(cfg, tmp_path / "near", progress=False).train()
    policy = LearnedPolicy.load(tmp_path / "near" / "actor.npz")
    env = deck_sim.load("deck1", seed=cfg.eval_seed, episode__predictor="mpc", **NEAR)
    learned = summarize([run_episode(env, policy, k) for k in range(10)])
    env.random_state.seed(cfg.eval_seed)
    rand = summarize([run_episode(env, RandomPolicy(0), k) for k in range(10)])
    assert learned["goal_rate"] == out["eval"]["goal_rate"]  # the exported file is the evaluated actor
    assert learned["goal_rate"] >= 0.6 and learned["goal_rate"] >= rand["goal_rate"] + 0.4, (learned, rand)
    assert learned["mean_reward"] > rand["mean_reward"] + 50.0


def test_cli_trains_resumes_and_runs_the_exported_actor(tmp_path, capsys):
    from deck_sim.cli import main

    out = tmp_path / "cli"
    args = [
        "train",
        "--algo",
        "ddpg",
        "--scene",
        "deck1",
        "--steps",
        "60",
        "--out",
        str(out),
        "--quiet",
        "--set",
        "hidden=[16,16]",
        "--set",
        "demo_episodes=0",
        "--set",
        "pretrain_updates=0",
        "--set",
        "learning_starts=20",
        "--set",
        "batch_size=16",
        "--set",
        "eval_episodes=1",
        "--set",
        "num_envs=1",
        "--set",
        "eval_every=0",
        "--set",
        "log_every=20",
    ]
    assert main(args) == 0
    assert "held-out success" in capsys.readouterr().out
    assert json.loads((out / "config.json").read_text())["algo"] == "ddpg"
    assert main(["train", "--algo", "ddpg", "--out", str(out), "--resume", "--steps", "80", "--quiet"]) == 0
    assert load_checkpoint(out / "checkpoint.pt")["step"] == 80
    assert main(args) == 2  # the folder holds a run: refused, nothing overwritten
    assert "already holds a run" in capsys.readouterr().err
    assert main(["train", "--algo", "ddpg", "--out", str(out), "--set", "gamma=2"]) == 2
    assert "gamma" in capsys.readouterr().err
    assert (
        main(
            [
                "run",
                "--scene",
                "deck1",
                "--policy",
                str(out / "actor.npz"),
                "--episodes",
                "1",
                "--no-record",
                "--quiet",
                "--out",
                str(tmp_path / "eval"),
            ]
        )
        == 0
    )
    assert "predictor none" in capsys.readouterr().out  # DDPG's actor runs without prediction


def test_actor_files_refuse_garbage_and_the_wrong_scene(tmp_path, capsys):
    import deck_sim
    from deck_sim.cli import main
    from deck_sim.policies import LearnedPolicy, PolicyFileError

    run = tmp_path / "run"
    Trainer(
        _short(total_steps=20, demo_episodes=0, pretrain_updates=0, learning_starts=10), run, progress=False
    ).train()
    policy = LearnedPolicy.load(run / "actor.npz")
    env = deck_sim.load("deck2", seed=0, episode__predictor="mpc")
    with pytest.raises(PolicyFileError, match="shape"):
        policy.act(env.reset().observation)
    env = deck_sim.load("deck1", seed=0, episode__predictor="none")
    with pytest.raises(PolicyFileError, match="'predicted'"):
        policy.act(env.reset().observation)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(PolicyFileError, match="bad.npz: not a readable actor file"):
        LearnedPolicy.load(bad)
    with pytest.raises(PolicyFileError, match="no such actor file"):
        LearnedPolicy.load(tmp_path / "missing.npz")
    np.savez(bad, w0=np.zeros((2, 2)))
    with pytest.raises(PolicyFileError, match="no 'meta' record"):
        LearnedPolicy.load(bad)
    assert main(["run", "--scene", "deck1", "--policy", str(bad), "--episodes", "1", "--no-record"]) == 2
    assert "bad.npz" in capsys.readouterr().err


def test_exported_actor_acts_like_the_agent(tmp_path):
    from deck_sim.policies import LearnedPolicy

    t = Trainer(
        _short(total_steps=40, demo_episodes=1, pretrain_updates=10, obs_norm=True), tmp_path / "r", progress=False
    )
    t.train()
    policy = LearnedPolicy.load(tmp_path / "r" / "actor.npz")
    obs = t.buffer.obs[: t.buffer.size]
    np.testing.assert_allclose(policy.act_flat(obs), t.agent.act(obs), atol=1e-5)


@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_sb3_baselines_train_evaluate_and_resume(tmp_path, algo):
    from training.baselines import discrete_actions, load_baseline, train_baseline

    out = tmp_path / algo
    kwargs = {"learning_starts": 20, "buffer_size": 1000} if algo == "dqn" else {"n_steps": 8}
    summary = train_baseline(
        algo, "deck1", 48, 0, out, progress=False, eval_every=0, eval_episodes=1, log_every=16, **kwargs
    )
    assert summary["step"] == 48 and summary["eval"]["episodes"] == 1
    assert len(_rows(out / "progress.csv")) == 3 and len(_rows(out / "eval.csv")) == 1
    again = train_baseline(
        algo, "deck1", 64, 0, out, resume=True, progress=False, eval_every=0, eval_episodes=1, log_every=16
    )
    assert again["step"] == 64
    policy = load_baseline(out)
    import deck_sim

    env = deck_sim.load("deck1", seed=3, episode__predictor="none")
    action = policy.act(env.reset().observation)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    if algo == "dqn":
        assert any(np.allclose(action, row) for row in discrete_actions())


def test_left_out_movers_read_as_beyond_the_near_field():
    from training.envs import mover_pad_fills

    cfg = make_config(scene="square", scene_overrides={"episode__near_steps": 4, "episode__near_obstacles": True})
    fills = mover_pad_fills(cfg)
    near = 4 * 0.75  # the square's reach
    assert fills == {"dynamic_near": pytest.approx(near / np.sqrt(2))}
    assert mover_pad_fills(make_config(scene_overrides={"episode__predicted_frame": "mover"})) == {"predicted": 0.0}
    assert mover_pad_fills(make_config()) == {}
    full = ObservationLayout({"target": (2,), "dynamic_obstacles": (3, 2), "dynamic_near": (3, 2)})
    stage = ObservationLayout({"target": (2,), "dynamic_obstacles": (1, 2), "dynamic_near": (1, 2)})
    flat = np.arange(6, dtype=float)[None]
    padded = stage.pad_to(flat, full, fills).reshape(1, -1)
    sl = full.slices()
    rows = padded[0, sl["dynamic_near"]].reshape(3, 2)
    np.testing.assert_array_equal(rows[0], [4.0, 5.0])  # the stage's own mover, kept first
    np.testing.assert_allclose(np.linalg.norm(rows[1:], axis=1), near)  # the left-out ones: on the field's edge
    np.testing.assert_array_equal(padded[0, sl["dynamic_obstacles"]][2:], FAR)


def test_curriculum_stages_change_the_scene_not_the_observation(tmp_path):
    from training.config import CurriculumStage

    stages = (CurriculumStage(until=0.5, max_target_distance=60.0, movers=0),)
    t = Trainer(_short(total_steps=60, demo_episodes=0, pretrain_updates=0, curriculum=stages), tmp_path / "c",
                progress=False)
    seen = []
    for stop in (10, 40, 60):  # the first episodes start in stage 0; episodes started past half the run do not
        t.train(stop_at=stop)
        seen.append({s.stage for s in t.slots})
        for s in t.slots:
            assert s.obs.shape == (t.obs_dim,)
            movers = s.layout.shapes["dynamic_obstacles"][0]  # the stage's scene, before padding
            assert movers == (0 if s.stage == 0 else 5)
    assert seen[0] == {0}
    rows = t.buffer.obs[: t.buffer.size]
    dyn = t.layout.slices()["dynamic_obstacles"]
    assert np.all(rows[:10, dyn] == FAR)  # stage 0: every mover row is the far placeholder
    config = t.config.to_dict()
    assert TrainConfig.from_dict(json.loads(json.dumps(config))).curriculum == stages  # saved and read back


@pytest.mark.parametrize("scene", ["deck1", "deck2", "square"])
def test_the_shipped_policies_load_and_act_on_their_scene(scene):
    import deck_sim
    from deck_sim.policies import make_policy, policy_overrides, shipped_policy_path

    path = shipped_policy_path("mddpg", scene)
    assert path.stat().st_size < 2 * 1024 * 1024  # small, weights only
    overrides = policy_overrides("mddpg", scene)  # the actor's own observation options
    assert overrides["episode__predictor"] == "mpc"
    env = deck_sim.load(scene, seed=1000, **overrides)
    policy = make_policy("mddpg", env)
    assert policy.meta["scene"] == scene and policy.predictor == "mpc"
    ts = env.reset()
    for _ in range(3):
        action = policy.act(ts.observation)
        assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
        ts = env.step(action)


def test_an_agent_without_prediction_is_taught_by_the_planner_that_sees_the_forecasts():
    """Relabelling for DDPG (predictor ``none``): the planner plans on the MPC forecasts, as it does for MDDPG, and
    the agent's observation is the plain one (no ``predicted`` part), equal to a ``none`` environment's."""
    from deck_sim.policies import ScriptedPolicy
    from training.envs import make_env
    from training.runners import InlineEnvs

    seed, actions = 123, np.array([[0.6, 0.2], [0.7, -0.1], [0.5, 0.5], [0.8, 0.0]])
    envs = InlineEnvs(1)
    layout = envs.build(0, "deck1", "none", {}, True)
    assert "predicted" not in layout.keys
    plain = make_env("deck1", "none")
    taught = make_env("deck1", "mpc")
    teacher = ScriptedPolicy(taught.composer_env)
    obs = envs.reset(0, seed)
    plain_obs, _ = plain.reset(seed=seed)
    taught.reset(seed=seed)
    assert np.array_equal(obs, plain_obs)
    for a in actions:
        envs.step_async(a[None])
        res = envs.step_wait()[0]
        assert np.array_equal(res.expert, np.clip(teacher.act({}), -1.0, 1.0))
        plain_obs, *_ = plain.step(a)
        taught.step(a)
        assert np.array_equal(res.obs, plain_obs)
    envs.close()


def test_the_cloning_weight_falls_on_its_schedule_and_resumes_with_the_step():
    from training.config import arm_config, bc_weight_at

    cfg = arm_config("tuned-mddpg-with-decay", "deck1", steps=10_000, seed=0)
    assert (cfg.bc_weight, cfg.bc_weight_final, cfg.bc_decay) == (20.0, 2.0, 1.0)
    assert [bc_weight_at(cfg, s) for s in (0, 5_000, 10_000, 20_000)] == [20.0, 11.0, 2.0, 2.0]
    assert bc_weight_at(make_config(), 5_000) == 20.0  # no final weight: constant
    half = make_config(bc_weight=10.0, bc_weight_final=0.0, bc_decay=0.5, total_steps=1_000)
    assert bc_weight_at(half, 250) == 5.0 and bc_weight_at(half, 600) == 0.0
    with pytest.raises(ConfigError, match="bc_weight_final"):
        make_config(bc_weight_final=-1.0)
    with pytest.raises(ConfigError, match="bc_decay"):
        make_config(bc_decay=1.5)
    with pytest.raises(ConfigError, match="bc_weight_final: the cloning term is off"):
        make_config(bc_weight=0.0, bc_weight_final=2.0)
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg  # saved with the run


def test_recipe_switches_combine_with_plus_and_merge_scene_overrides():
    from training.config import arm_config

    cfg = arm_config("tuned-mddpg-with-data+size+shape", "deck1", steps=10_000, seed=0)
    assert (cfg.num_envs, cfg.updates_per_step) == (8, 0.125)
    assert cfg.scene_overrides == {"episode__mover_size": True, "episode__obstacle_shape": True}
    assert arm_config("tuned-ddpg-with-data", "deck1", steps=10_000, seed=0).num_envs == 8
    near = arm_config("tuned-mddpg-with-data+polish+near", "square", steps=10_000, seed=0)
    assert near.scene_overrides == {"episode__near_steps": 4} and near.polish_epochs == 20
    ego = arm_config("tuned-ddpg-with-data+polish+size+ego", "deck1", steps=10_000, seed=0)
    assert ego.scene_overrides == {"episode__mover_size": True, "episode__frame": "agent"}
    close = arm_config("tuned-mddpg-with-data+polish+near+sets+close", "square", steps=10_000, seed=0)
    assert close.scene_overrides == {"episode__near_steps": 4, "episode__near_obstacles": True}
    assert close.actor_arch == "sets"
    assert arm_config("tuned-ddpg-with-data+body", "deck1", steps=10_000, seed=0).teacher_body
    assert not arm_config("tuned-ddpg-with-data", "deck1", steps=10_000, seed=0).teacher_body
    from training.config import SHIPPED_RECIPES, shipped_arm

    for scene in SHIPPED_RECIPES:  # every shipped recipe is a valid arm
        arm = shipped_arm(scene, "ddpg")
        assert arm_config(arm.recipe, scene, arm.steps, 0, arm.eval_every, arm.eval_episodes).algo == "ddpg"
    assert shipped_arm("deck1", "mddpg")[:4] == (
        "tuned-mddpg-with-data+polish+size+sets+body+dagger", 160_000, 20_000, 100
    )
    deck1 = arm_config(shipped_arm("deck1", "ddpg").recipe, "deck1", 160_000, 0)
    assert (deck1.actor_arch, deck1.polish_epochs, deck1.scene_overrides) == ("sets", 20, {"episode__mover_size": True})
    assert deck1.teacher_body and deck1.dagger_steps == 40_000
    assert shipped_arm("deck2", "ddpg")[:2] == ("tuned-ddpg-with-data+polish+size+sets+close", 160_000)
    for deck in ("deck1", "deck2", "square"):  # two seeds' actors averaged, MDDPG and DDPG alike
        assert shipped_arm(deck, "ddpg").seeds == shipped_arm(deck, "mddpg").seeds == (0, 1)
    assert shipped_arm("square", "mddpg") == (
        "tuned-mddpg-with-data+polish+near+sets+close", 160_000, 20_000, 100, (0, 1)
    )
    for bad in ("tuned-mddpg-with-data+nope", "tuned-mddpg-with-data+data", "tuned-mddpg-no-data"):
        with pytest.raises(ConfigError, match="unknown switch"):
            arm_config(bad, "deck1", steps=10_000, seed=0)


def test_polishing_fits_the_buffer_and_a_finished_run_can_be_polished_later(tmp_path):
    """The final cloning fit lowers the cloning loss over the buffer, adds a marked evaluation at the last step,
    and gives the same actor whether it was asked for from the start or added by resuming the finished run."""
    polished = Trainer(_short(polish_epochs=30), tmp_path / "polished", progress=False)
    polished.train()
    plain = Trainer(_short(), tmp_path / "plain", progress=False)
    plain.train()
    rows = np.flatnonzero(plain.buffer.labelled[: plain.buffer.size] > 0)
    assert len(rows) == plain.buffer.size  # demonstrations and relabelled transitions all carry the planner's label

    def cloning_loss(trainer: Trainer) -> float:
        with torch.no_grad():
            obs = trainer.agent.norm(torch.as_tensor(trainer.buffer.obs[rows]))
            err = trainer.agent.actor(obs) - torch.as_tensor(trainer.buffer.expert_action[rows])
        return float((err**2).sum(-1).mean())

    assert cloning_loss(polished) < 0.5 * cloning_loss(plain)
    evals = _rows(tmp_path / "polished" / "eval.csv")
    assert [(r["step"], r["polished"]) for r in evals] == [("120", "0"), ("120", "1")]
    meta = json.loads(str(np.load(tmp_path / "polished" / "actor.npz", allow_pickle=False)["meta"]))
    assert meta["polished"] is True
    # what is shipped: the fitted final actor, else the best evaluation's
    assert shipped_actor(tmp_path / "polished") == tmp_path / "polished" / "actor.npz"
    assert shipped_actor(tmp_path / "plain") == tmp_path / "plain" / "actor_best.npz"
    later = Trainer(_short(polish_epochs=30), tmp_path / "plain", resume=True, progress=False)
    later.train()
    assert shipped_actor(tmp_path / "plain") == tmp_path / "plain" / "actor.npz"
    assert [r["polished"] for r in _rows(tmp_path / "plain" / "eval.csv")] == ["0", "1"]  # no second online row
    assert _rows(tmp_path / "plain" / "eval.csv") == evals
    for name in ("actor.npz", "actor_best.npz"):
        with np.load(tmp_path / "polished" / name) as a, np.load(tmp_path / "plain" / name) as b:
            for k in a.files:
                if k != "meta":
                    np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name} {k}")
    again = Trainer(_short(polish_epochs=30), tmp_path / "plain", resume=True, progress=False)
    again.train()  # polished once: resuming again changes nothing
    assert len(_rows(tmp_path / "plain" / "eval.csv")) == 2
    # a polished run is finished: neither extended nor polished again with other settings
    with pytest.raises(CheckpointError, match="cannot be extended"):
        Trainer(_short(polish_epochs=30, total_steps=160), tmp_path / "plain", resume=True, progress=False).train()
    with pytest.raises(CheckpointError, match="polished with polish_epochs = 30"):
        Trainer(_short(polish_epochs=5), tmp_path / "plain", resume=True, progress=False).train()
    for bad in (-1, 2.0):
        with pytest.raises(ConfigError, match="polish_epochs"):
            make_config(polish_epochs=bad)


def test_a_dagger_round_labels_the_fitted_actors_own_states_and_fits_again(tmp_path):
    """``dagger_steps``: after the final fit the fitted actor drives more steps, greedy and without updates (the
    critic and the normaliser stay as they are), every state labelled by the planner, then the fit is made again
    on all of them and evaluated; asking for the round from the start or adding it to a fitted run by resuming
    gives the same actor; a round is neither repeated nor undone."""
    from training.config import arm_config

    fitted = Trainer(_short(polish_epochs=5), tmp_path / "fitted", progress=False)
    fitted.train()
    size, critic = fitted.buffer.size, [p.detach().clone() for p in fitted.agent.critic.parameters()]
    norm = fitted.agent.norm.state_dict()
    later = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "fitted", resume=True, progress=False)
    later.train()
    assert later.step == 160 and later.buffer.size == size + 40 and later.dagger_done == 40
    rows = np.flatnonzero(later.buffer.labelled[: later.buffer.size] > 0)
    assert len(rows) == later.buffer.size  # the round's states carry the planner's label too
    # the round acted with the fitted actor's greedy action: stored actions are that actor's on the stored states
    greedy = fitted.agent.act(later.buffer.obs[size : size + 40])
    np.testing.assert_allclose(later.buffer.action[size : size + 40], np.clip(greedy, -1, 1), rtol=0, atol=1e-6)
    for a, b in zip(critic, later.agent.critic.parameters(), strict=True):  # no updates
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    for k, v in norm.items():
        torch.testing.assert_close(v, later.agent.norm.state_dict()[k], rtol=0, atol=0)
    evals = _rows(tmp_path / "fitted" / "eval.csv")
    assert [(r["step"], r["polished"]) for r in evals] == [("120", "0"), ("120", "1"), ("160", "1")]
    meta = json.loads(str(np.load(tmp_path / "fitted" / "actor.npz", allow_pickle=False)["meta"]))
    assert meta["polished"] is True and meta["trained_steps"] == 160 and meta["config"]["dagger_steps"] == 40
    # from the start: the same actor and evaluations
    whole = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "whole", progress=False)
    whole.train()
    assert _rows(tmp_path / "whole" / "eval.csv") == evals
    for k, v in _actor_arrays(tmp_path / "whole").items():
        np.testing.assert_array_equal(v, _actor_arrays(tmp_path / "fitted")[k], err_msg=k)
    # stopped halfway through the round (it starts at step 120): no actor, the fitted checkpoint stays; resumed,
    # the round starts again from there and ends as the uninterrupted run
    stopped = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "stopped", progress=False)
    tick = stopped._tick

    def tick_then_stop() -> None:
        tick()
        stopped._stop = stopped._stop or stopped.step >= 140

    stopped._tick = tick_then_stop
    stopped.train()
    assert not (tmp_path / "stopped" / "actor.npz").exists()
    saved = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt")
    assert (saved["step"], saved["polished"], saved["dagger_done"]) == (120, True, 0)
    Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "stopped", resume=True, progress=False).train()
    assert _rows(tmp_path / "stopped" / "eval.csv") == evals
    for k, v in _actor_arrays(tmp_path / "whole").items():
        np.testing.assert_array_equal(v, _actor_arrays(tmp_path / "stopped")[k], err_msg=k)
    again = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "whole", resume=True, progress=False)
    again.train()  # the round is done: resuming changes nothing
    assert again.step == 160 and len(_rows(tmp_path / "whole" / "eval.csv")) == 3
    with pytest.raises(CheckpointError, match="DAgger round of 40 steps"):
        Trainer(_short(polish_epochs=5), tmp_path / "whole", resume=True, progress=False).train()
    with pytest.raises(ConfigError, match="dagger_steps: needs the final fit"):
        make_config(dagger_steps=40)
    for bad in (-1, 2.5, True):
        with pytest.raises(ConfigError, match="dagger_steps"):
            make_config(polish_epochs=5, dagger_steps=bad)
    assert arm_config("tuned-mddpg-with-data+polish+dagger", "deck1", steps=10_000, seed=0).dagger_steps == 40_000


def test_a_wider_final_fit_exports_an_actor_of_its_own_widths_and_resumes(tmp_path):
    """``polish_hidden``: the final fit trains a fresh actor of other widths (the critic keeps ``hidden``); the
    exported file has those widths and acts; the polished run resumes with that actor; a finished run can be
    given the wider fit later, and not twice."""
    import deck_sim
    from deck_sim.policies import LearnedPolicy

    cfg = _short(polish_epochs=5, polish_hidden=(24, 16, 8))
    wide = Trainer(cfg, tmp_path / "wide", progress=False)
    wide.train()
    with np.load(tmp_path / "wide" / "actor.npz") as f:
        assert [f[f"w{i}"].shape for i in range(4)] == [(24, wide.obs_dim), (16, 24), (8, 16), (2, 8)]
        assert "w4" not in f.files
    policy = LearnedPolicy.load(tmp_path / "wide" / "actor.npz")
    env = deck_sim.load("deck1", seed=0, **policy.scene_overrides)
    action = policy.act(env.reset().observation)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    again = Trainer(cfg, tmp_path / "wide", resume=True, progress=False)
    again.train()  # restores the polished checkpoint into an actor of the fit's widths
    for a, b in zip(wide.agent.actor.parameters(), again.agent.actor.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    # a finished, unpolished run given the wider fit later: the same actor as asking for it from the start
    Trainer(_short(), tmp_path / "later", progress=False).train()
    Trainer(cfg, tmp_path / "later", resume=True, progress=False).train()
    with np.load(tmp_path / "wide" / "actor.npz") as a, np.load(tmp_path / "later" / "actor.npz") as b:
        for k in a.files:
            if k != "meta":
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    with pytest.raises(CheckpointError, match="polished with polish_hidden"):
        Trainer(_short(polish_epochs=5, polish_hidden=(32,)), tmp_path / "later", resume=True, progress=False).train()
    with pytest.raises(ConfigError, match="polish_hidden"):
        make_config(polish_hidden=(0, 8))


def test_cli_resume_may_add_polishing_but_no_other_change(tmp_path, capsys):
    from deck_sim.cli import main

    out = tmp_path / "run"
    Trainer(_short(total_steps=60, demo_episodes=0, pretrain_updates=0), out, progress=False).train()
    base = ["train", "--algo", "mddpg", "--out", str(out), "--resume", "--quiet"]
    assert main([*base, "--set", "gamma=0.5"]) == 2
    err = capsys.readouterr().err
    assert "may change only total_steps, polish_epochs, polish_lr, polish_hidden, dagger_steps, not gamma" in err
    assert main([*base, "--set", "polish_epochs=2"]) == 0
    assert load_checkpoint(out / "checkpoint.pt")["polished"] is True


def test_an_actor_file_asks_for_the_observation_options_it_was_trained_with(tmp_path):
    import deck_sim
    from deck_sim.policies import LearnedPolicy, PolicyFileError
    from deck_sim.scenes import SceneSpecError

    overrides = {
        "episode__predicted_frame": "mover",
        "episode__mover_size": True,
        "episode__near_steps": 2,
        "episode__near_obstacles": True,
        "episode__route_steps": 3,
        "episode__frame": "agent",  # the same keys and shapes as the deck's axes: only the record tells them apart
    }
    t = Trainer(
        _short(total_steps=20, demo_episodes=0, pretrain_updates=0, learning_starts=10, scene_overrides=overrides),
        tmp_path / "r",
        progress=False,
    )
    t.train()
    policy = LearnedPolicy.load(tmp_path / "r" / "actor.npz")
    assert policy.scene_overrides == {"episode__predictor": "mpc", **overrides}
    # every field that changes what an observation or action means without changing a shape is carried over
    policy.meta["scene_overrides"]["episode__control_period"] = 0.4
    assert policy.scene_overrides["episode__control_period"] == 0.4
    policy.meta["scene_overrides"]["episode__time_limit"] = 30.0  # the task's, not the actor's: not carried
    assert "episode__time_limit" not in policy.scene_overrides
    del policy.meta["scene_overrides"]["episode__control_period"], policy.meta["scene_overrides"]["episode__time_limit"]
    assert "dynamic_size" in policy.keys and "target_near" in policy.keys and "edge_near" in policy.keys
    assert "static_near" in policy.keys and "dynamic_near" in policy.keys
    assert policy.shapes["route"] == (3, 2)
    # an actor whose near field came from its scene file asks for no range; a scene without one is refused
    del policy.meta["scene_overrides"]["episode__near_steps"]
    assert "episode__near_steps" not in policy.scene_overrides
    with pytest.raises(SceneSpecError, match="near_obstacles: needs a near field"):  # its near obstacles need one
        deck_sim.load("deck1", seed=0, **policy.scene_overrides)
    overrides = {k: v for k, v in policy.scene_overrides.items() if k != "episode__near_obstacles"}
    env = deck_sim.load("deck1", seed=0, **overrides)
    with pytest.raises(PolicyFileError, match="needs observation 'target_near'"):
        policy.flatten(env.reset().observation)
