"""The DDPG agent's parts by hand (TD target, losses, twin critics, cloning term, soft update), the replay
buffer, and the observation layouts and environments the trainer feeds it (padding of left-out movers, the
planner's labels for an agent without prediction)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from training.buffers import ReplayBuffer
from training.config import TrainConfig, make_config
from training.ddpg import DDPGAgent, soft_update
from training.envs import FAR, ObservationLayout


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


def test_prioritised_weights_scale_each_squared_error_and_the_td_errors_are_kept():
    agent = _tiny_agent()
    batch = _batch([[1.0, 0.0], [0.5, 0.5]], [[0.5], [-1.0]], [1.0, -2.0], [[2.0, 1.0], [0.0, 3.0]], [0.0, 1.0])
    q_next0 = 3.0 * (3.0 + 2.0 * np.tanh(0.5)) + 1.0
    y = np.array([1.0 + 0.9 * q_next0, -2.0])
    q = np.array([3.0 * (1.0 + 2.0 * 0.5) + 1.0, 1.0])
    stats = agent.update(batch._replace(weight=torch.tensor([0.25, 1.0])))
    np.testing.assert_allclose(stats["critic_loss"], (0.25 * (q[0] - y[0]) ** 2 + (q[1] - y[1]) ** 2) / 2, rtol=1e-6)
    np.testing.assert_allclose(agent.last_td_error, q - y, rtol=1e-6)


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


@pytest.mark.parametrize("weight", [1.0, 0.75, 0.5])
def test_the_twin_target_weighs_the_smaller_and_the_larger_critic(weight):
    agent = _tiny_agent(twin_critics=True, twin_min_weight=weight)
    with torch.no_grad():  # second target head 5 below the first whatever the input
        agent.critic_target.heads[1][2].bias.fill_(-4.0)
    batch = _batch([[1.0, 0.0]], [[0.5]], [0.0], [[2.0, 1.0]], [0.0])
    larger = 3.0 * (3.0 + 2.0 * np.tanh(0.5)) + 1.0
    y = 0.9 * (weight * (larger - 5.0) + (1.0 - weight) * larger)
    np.testing.assert_allclose(agent.td_target(batch).numpy(), [y], rtol=1e-6)


def test_twin_min_weight_outside_zero_to_one_or_without_twins_is_refused_by_name():
    from training.config import ConfigError

    with pytest.raises(ConfigError, match="twin_min_weight"):
        make_config("reward", twin_min_weight=1.5)
    with pytest.raises(ConfigError, match="twin_min_weight: weighs the twin critics, which are off"):
        make_config("paper", twin_min_weight=0.5)


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


def _hidden_and_output_dtypes(agent: DDPGAgent, obs: torch.Tensor, action: torch.Tensor) -> list[torch.dtype]:
    """The dtypes of the first critic's linear layers' outputs in one forward pass inside ``agent.precision()``."""
    seen: list[torch.dtype] = []
    hooks = [m.register_forward_hook(lambda _m, _i, out: seen.append(out.dtype))
             for m in agent.critic.heads[0] if isinstance(m, torch.nn.Linear)]
    try:
        with agent.precision():
            q = agent.critic.first(obs, action)
    finally:
        for h in hooks:
            h.remove()
    return [*seen, q.dtype]


def test_bfloat16_updates_run_the_hidden_layers_in_bfloat16_and_keep_outputs_and_weights_float32():
    torch.manual_seed(0)
    obs, action = torch.randn(64, 6), torch.rand(64, 2) * 2 - 1
    batch = _batch(obs.tolist(), action.tolist(), torch.randn(64).tolist(), torch.randn(64, 6).tolist(), [0.0] * 64)
    agents = {}
    for precision in ("float32", "bfloat16"):
        torch.manual_seed(1)
        agents[precision] = DDPGAgent(6, 2, TrainConfig(hidden=(64, 64), learner_precision=precision))
    full, half = agents["float32"], agents["bfloat16"]
    assert _hidden_and_output_dtypes(full, obs, action) == [torch.float32] * 4
    assert _hidden_and_output_dtypes(half, obs, action) == [torch.bfloat16, torch.bfloat16, torch.float32,
                                                           torch.float32]
    with half.precision():
        assert half.actor(obs).dtype == torch.float32
    # the same networks: the two precisions agree to bfloat16's resolution, and differ beyond it
    q_full = full.critic.first(obs, action)
    with half.precision():
        q_half = half.critic.first(obs, action)
    assert torch.allclose(q_full, q_half, atol=0.02) and not torch.equal(q_full, q_half)
    for _ in range(3):
        stats = {p: a.update(batch) for p, a in agents.items()}
    assert stats["bfloat16"]["critic_loss"] == pytest.approx(stats["float32"]["critic_loss"], rel=0.05)
    assert all(p.dtype == torch.float32 for p in half.critic.parameters())
    assert all(p.dtype == torch.float32 for p in half.actor.parameters())
    assert {a.dtype for a in half.export_actor().values() if a.dtype.kind == "f"} == {np.dtype(np.float32)}
    # acting is float32 either way: the exported actor acts exactly as the live one outside the updates
    np.testing.assert_array_equal(half.act(obs.numpy()), half.acting()(obs.numpy()))
    assert not torch.is_autocast_enabled("cpu")


def test_an_unknown_learner_precision_is_refused_by_name():
    from training.config import ConfigError

    with pytest.raises(ConfigError, match="learner_precision: expected one of float32, bfloat16, got 'float16'"):
        make_config("reward", learner_precision="float16")


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
    # a left-out mover's closest approach: now, as far away as its FAR position
    full_a = ObservationLayout({"predicted_approach": (3, 2)})
    small_a = ObservationLayout({"predicted_approach": (1, 2)})
    out = small_a.pad_to(np.ones(small_a.dim, dtype=np.float32), full_a)
    np.testing.assert_allclose(out, [1, 1] + [0, FAR * np.sqrt(2)] * 2, rtol=1e-6)


def test_left_out_movers_read_as_beyond_the_near_field():
    from training.envs import mover_pad_fills

    cfg = make_config(scene="square", scene_overrides={"episode__near_steps": 4, "episode__near_obstacles": True})
    fills = mover_pad_fills(cfg)
    near = 4 * 0.75  # the square's reach
    assert fills == {"dynamic_near": pytest.approx(near / np.sqrt(2))}
    both = make_config(scene="square", scene_overrides={"episode__near_steps": 4, "episode__predicted_near": True})
    assert mover_pad_fills(both) == {"predicted_near": pytest.approx(near / np.sqrt(2))}
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
    # the near forecast pads the same way, every forecast step of a left-out mover on the field's edge
    full_f = ObservationLayout({"dynamic_near": (3, 2), "predicted_near": (3, 2, 2)})
    stage_f = ObservationLayout({"dynamic_near": (1, 2), "predicted_near": (1, 2, 2)})
    both = make_config(scene="square", scene_overrides={
        "episode__near_steps": 4, "episode__near_obstacles": True, "episode__predicted_near": True})
    out = stage_f.pad_to(np.ones(stage_f.dim), full_f, mover_pad_fills(both)).reshape(-1)
    forecast = out[full_f.slices()["predicted_near"]].reshape(3, 2, 2)
    np.testing.assert_array_equal(forecast[0], 1.0)
    np.testing.assert_allclose(np.linalg.norm(forecast[1:], axis=-1), near)


@pytest.mark.slow
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


def test_the_layer_norm_critic_normalises_each_hidden_layer_by_hand():
    from training.config import arm_config

    cfg = arm_config("reward-mddpg-with-layernorm+utd", "deck1", steps=10_000, seed=0)
    assert cfg.critic_layer_norm and cfg.updates_per_step == 1.0
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
    agent = DDPGAgent(2, 1, TrainConfig(hidden=(3,), twin_critics=True, critic_layer_norm=True))
    plain = DDPGAgent(2, 1, TrainConfig(hidden=(3,), twin_critics=True))
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in plain.critic.modules())
    assert all(isinstance(h[1], torch.nn.LayerNorm) for h in (*agent.critic.heads, *agent.critic_target.heads))
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in agent.actor.modules())  # the actor unchanged
    head = agent.critic.heads[0]
    _set_linear(head[0], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 4.0]], [0.0, 0.0, 0.0])
    _set_linear(head[3], [[1.0, 2.0, 3.0]], [0.5])
    x = np.array([1.0, -2.0, 0.25])  # observation (1, -2), action 0.25
    z = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 4.0]]) @ x
    h = np.maximum((z - z.mean()) / np.sqrt(z.var() + 1e-5), 0.0)
    q = agent.critic.first(torch.tensor([[1.0, -2.0]]), torch.tensor([[0.25]]))
    np.testing.assert_allclose(q.detach().numpy(), [h @ [1.0, 2.0, 3.0] + 0.5], rtol=1e-5)


def _saturated_agent(weight: float) -> DDPGAgent:
    """obs 2, action 1; the actor's pre-tanh action is 30 on every state (tanh(30) == 1.0 in float32), and the
    critic rates a smaller action higher (Q falls with a through every ReLU unit it reads); a large actor step
    size, so that 50 Adam steps move it visibly."""
    torch.manual_seed(0)
    cfg = TrainConfig(hidden=(8,), batch_size=4, policy_delay=1, actor_lr=0.05, actor_preact_weight=weight)
    agent = DDPGAgent(2, 1, cfg)
    for net in (agent.actor, agent.actor_target):
        _set_linear(net.net[2], [[0.1] * 8], [30.0])
    with torch.no_grad():
        for head in agent.critic.heads:
            head[0].weight[:, 2] = -head[0].weight[:, 2].abs()
            head[2].weight.copy_(head[2].weight.abs())
    return agent


def test_the_preactivation_penalty_moves_a_saturated_actor_that_the_critic_cannot_move():
    from training.config import ConfigError, arm_config

    cfg = arm_config("reward-mddpg-with-preact", "deck1", steps=10_000, seed=0)
    assert cfg.actor_preact_weight == 1e-3 and TrainConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError, match="actor_preact_weight: must be a finite number >= 0, got -0.1"):
        make_config("reward", actor_preact_weight=-0.1)
    obs = torch.tensor([[1.0, 0.0], [0.5, 2.0], [0.0, 1.0], [2.0, 2.0]])
    batch = _batch(obs.tolist(), [[0.0]] * 4, [0.0] * 4, obs.tolist(), [1.0] * 4)
    pre = {}
    for weight in (0.0, 1e-3):
        agent = _saturated_agent(weight)
        assert torch.allclose(torch.tanh(agent.actor.preactivation(obs)), agent.actor(obs))
        before = copy.deepcopy(agent.actor.state_dict())
        for _ in range(50):
            agent.update(batch)
        pre[weight] = agent.actor.preactivation(obs).detach()
        changed = any(not torch.equal(before[k], v) for k, v in agent.actor.state_dict().items())
        assert changed == (weight > 0.0)  # without the penalty tanh's gradient is 0: the actor cannot move
    assert torch.all(pre[0.0] > 29.0) and torch.all(pre[1e-3] < pre[0.0] - 1.0)
    # a cloning-only update (pretraining) leaves the penalty out: the cloning loss alone, 0 through tanh(30)
    agent = _saturated_agent(1e-3)
    before = copy.deepcopy(agent.actor.state_dict())
    labelled = batch._replace(expert_action=torch.full((4, 1), -0.5), labelled=torch.ones(4))
    for _ in range(5):
        agent.update(labelled, clone_only=True)
    assert all(torch.equal(before[k], v) for k, v in agent.actor.state_dict().items())


@pytest.mark.parametrize("arch", ["mlp", "sets"])
def test_the_actors_preactivation_is_its_action_before_tanh_in_float32_and_under_bfloat16(arch):
    torch.manual_seed(3)
    shapes = {"target": (2,), "dynamic_obstacles": (3, 2), "position": (2,)}
    agent = DDPGAgent(10, 2, TrainConfig(hidden=(16, 16), set_hidden=(8,), actor_arch=arch), shapes=shapes)
    x = torch.randn(32, 10)
    with torch.no_grad():
        u = agent.actor.preactivation(x)
        assert u.abs().max() < 3.0  # away from saturation, where tanh tells values apart
        torch.testing.assert_close(torch.tanh(u), agent.actor(x))
        with torch.autocast("cpu", dtype=torch.bfloat16):
            u16, a16 = agent.actor.preactivation(x), agent.actor(x)
        assert u16.dtype == a16.dtype == torch.float32
        torch.testing.assert_close(torch.tanh(u16), a16)
