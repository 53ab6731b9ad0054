"""The set actor (``actor_arch = "sets"``): one shared encoder per set of obstacles, max-pooled.

Checked through the public API on the deck's real observation layout: the exported file acts as the torch actor
does, the action does not depend on the order of the movers, the tied normaliser pools each set's statistics, a
short training run with it exports, resumes and polishes, and broken files are refused by name.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import NEAR, short_config

from deck_sim.policies import (
    ACTOR_FORMAT_SETS,
    EnsemblePolicy,
    LearnedPolicy,
    PolicyFileError,
    load_actor,
    obstacle_sets,
    set_indices,
)
from training.config import ConfigError, TrainConfig, make_config
from training.ddpg import DDPGAgent
from training.envs import env_layout, make_env
from training.loop import Trainer


@pytest.fixture(scope="module")
def shapes():
    """The deck 1 MDDPG observation with the movers' sizes (the shipped recipe's), from the real scene."""
    env = make_env("deck1", "mpc", episode__mover_size=True)
    layout = env_layout(env)
    env.close()
    return layout.shapes


def _agent(shapes, seed: int = 0) -> DDPGAgent:  # noqa: ANN001
    torch.manual_seed(seed)
    cfg = TrainConfig(hidden=(32, 16), set_hidden=(16, 8), obs_norm=True, actor_arch="sets")
    dim = sum(int(np.prod(s)) for s in shapes.values())
    agent = DDPGAgent(dim, 2, cfg, shapes=shapes)
    rng = np.random.default_rng(seed)
    agent.norm.update(rng.normal(3.0, 20.0, size=(64, dim)))
    return agent


def _policy(agent: DDPGAgent) -> LearnedPolicy:
    meta = {
        **agent.actor_meta(),
        "observation_keys": list(agent.shapes),
        "observation_shapes": {k: list(v) for k, v in agent.shapes.items()},
    }
    return LearnedPolicy(agent.export_actor(), meta)


def test_the_set_layout_reads_each_obstacle_row_across_its_keys(shapes):
    sets = obstacle_sets(shapes)
    assert sets == {"movers": ["dynamic_obstacles", "predicted", "dynamic_size"], "statics": ["static_obstacles"]}
    context, elements = set_indices(shapes, sets)
    n, horizon = shapes["dynamic_obstacles"][0], shapes["predicted"][1]
    assert elements["movers"].shape == (n, 2 + 2 * horizon + 2)
    assert elements["statics"].shape == (shapes["static_obstacles"][0], 2)
    flat = np.concatenate([np.full(int(np.prod(s)), i, dtype=float) for i, s in enumerate(shapes.values())])
    keys = list(shapes)
    # every index appears exactly once, in the context or in one set
    every = np.concatenate([context, *(e.ravel() for e in elements.values())])
    assert sorted(every) == list(range(len(flat)))
    assert {keys[int(i)] for i in flat[context]} == {"target", "position", "velocity", "heading"}
    # mover 2's row: its position now, then its forecast, then its size
    start = {k: sum(int(np.prod(shapes[j])) for j in keys[: keys.index(k)]) for k in keys}
    row = elements["movers"][2]
    assert list(row[:2]) == [start["dynamic_obstacles"] + 4, start["dynamic_obstacles"] + 5]
    assert row[2] == start["predicted"] + 2 * horizon * 2
    assert list(row[-2:]) == [start["dynamic_size"] + 4, start["dynamic_size"] + 5]
    with pytest.raises(ValueError, match="first dimensions"):
        set_indices(shapes, {"mixed": ["dynamic_obstacles", "static_obstacles"]})


@pytest.mark.parametrize(
    "shape_fields,near_fields",
    [(False, False), (True, False), (True, True), (True, "forecast")],
    ids=["paper-observation", "obstacle-shapes", "shapes-and-near-obstacles", "and-the-near-forecast"],
)
def test_each_obstacle_row_gathers_that_obstacles_values_from_every_key_of_its_set(shape_fields, near_fields):
    # an observation whose every entry names its key, obstacle and column, flattened as the policy flattens it;
    # each row of a set must be that obstacle's values, key after key (a check that does not use set_indices' own
    # arithmetic)
    near = {"episode__near_steps": 4, "episode__near_obstacles": True} if near_fields else {}
    if near_fields == "forecast":
        near["episode__predicted_near"] = True
    env = make_env("deck1", "mpc", episode__mover_size=True, episode__obstacle_shape=shape_fields, **near)
    shapes = env_layout(env).shapes
    env.close()
    sets = obstacle_sets(shapes)
    if near_fields:
        assert sets["statics"] == ["static_obstacles", "static_nearest", "static_near"]
        tail = ["dynamic_nearest", "dynamic_heading", "dynamic_near"]
        expected = tail + ["predicted_near"] if near_fields == "forecast" else ["dynamic_size"] + tail
        assert sets["movers"][-4:] == expected
        assert "target_near" in shapes and "edge_near" in shapes  # the near field's own keys: context
    elif shape_fields:
        assert sets["statics"] == ["static_obstacles", "static_nearest"]
        assert sets["movers"][-2:] == ["dynamic_nearest", "dynamic_heading"]
    observation = {
        k: (1000.0 * i + np.arange(int(np.prod(s)), dtype=float)).reshape(s) for i, (k, s) in enumerate(shapes.items())
    }
    meta = {"format": "deck_sim.actor/1", "observation_keys": list(shapes),
            "observation_shapes": {k: list(v) for k, v in shapes.items()}}
    dim = sum(int(np.prod(s)) for s in shapes.values())
    flat = LearnedPolicy({"w0": np.zeros((2, dim)), "b0": np.zeros(2), "norm_enabled": np.array(False),
                          "norm_mean": np.zeros(dim), "norm_std": np.ones(dim), "norm_clip": np.array(10.0)},
                         meta).flatten(observation)
    context, elements = set_indices(shapes, sets)
    for name, keys in sets.items():
        for j in range(shapes[keys[0]][0]):
            expected = np.concatenate([observation[k][j].ravel() for k in keys])
            np.testing.assert_array_equal(flat[elements[name][j]], expected, err_msg=f"{name} row {j}")
    in_sets = {k for keys in sets.values() for k in keys}
    expected_context = np.concatenate([observation[k].ravel() for k in shapes if k not in in_sets])
    np.testing.assert_array_equal(flat[context], expected_context)


def test_the_exported_set_actor_acts_as_the_torch_one_whatever_the_order_of_the_movers(shapes):
    agent = _agent(shapes)
    policy = _policy(agent)
    assert policy.meta["format"] == ACTOR_FORMAT_SETS
    rng = np.random.default_rng(1)
    x = rng.normal(3.0, 20.0, size=(50, agent.obs_dim))
    np.testing.assert_allclose(policy.act_flat(x), agent.act(x), atol=1e-5)
    # the same movers in another order (all of a mover's rows together): the same action
    _, elements = set_indices(shapes, policy.sets)
    rows = elements["movers"]
    perm = np.roll(np.arange(len(rows)), 2)
    shuffled = x.copy()
    shuffled[:, rows.ravel()] = x[:, rows[perm].ravel()]
    assert not np.allclose(shuffled, x)
    np.testing.assert_allclose(policy.act_flat(shuffled), policy.act_flat(x), atol=1e-12)
    np.testing.assert_allclose(agent.act(shuffled), agent.act(x), atol=1e-5)


def test_the_tied_normaliser_pools_each_feature_over_the_obstacles(shapes):
    agent = _agent(shapes)
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 1.0, size=(500, agent.obs_dim)) * rng.uniform(1, 30, agent.obs_dim) + rng.uniform(
        -50, 50, agent.obs_dim
    )
    agent.norm = type(agent.norm)(agent.obs_dim)
    _, elements = set_indices(shapes, agent.sets)
    agent.norm.tie(list(elements.values()))
    agent.norm.update(x)
    mean, std = (t.numpy() for t in agent.norm.stats())
    for idx in elements.values():
        for f in range(idx.shape[1]):
            column = x[:, idx[:, f]].ravel()  # feature f of every obstacle, all pooled
            np.testing.assert_allclose(mean[idx[:, f]], column.mean(), rtol=1e-6)
            np.testing.assert_allclose(std[idx[:, f]], column.std(), rtol=1e-6)
    context, _ = set_indices(shapes, agent.sets)
    np.testing.assert_allclose(mean[context], x[:, context].mean(0), rtol=1e-6)
    np.testing.assert_allclose(std[context], x[:, context].std(0), rtol=1e-5)


def test_broken_set_actor_files_are_refused_by_name(shapes, tmp_path):
    agent = _agent(shapes)
    arrays, meta = agent.export_actor(), _policy(agent).meta
    missing = {k: v for k, v in arrays.items() if not k.startswith("movers.")}
    with pytest.raises(PolicyFileError, match="set 'movers' has no encoder layers"):
        LearnedPolicy(missing, meta)
    bad = dict(arrays, **{"statics.w0": arrays["statics.w0"][:, :-1]})
    with pytest.raises(PolicyFileError, match="set 'statics'.*layer 0"):
        LearnedPolicy(bad, meta)
    narrow = dict(arrays, w0=arrays["w0"][:, :-1])
    with pytest.raises(PolicyFileError, match="layer 0"):
        LearnedPolicy(narrow, meta)
    with pytest.raises(PolicyFileError, match="not in the observation"):
        LearnedPolicy(arrays, {**meta, "sets": {"movers": ["dynamic_obstacles", "no_such_key"]}})
    nan = dict(arrays, **{"movers.b1": np.full_like(arrays["movers.b1"], np.nan)})
    with pytest.raises(PolicyFileError, match="NaN"):
        LearnedPolicy(nan, meta)
    with pytest.raises(PolicyFileError, match="not a complete deck_sim actor"):
        LearnedPolicy(arrays, {k: v for k, v in meta.items() if k != "sets"})
    with pytest.raises(PolicyFileError, match="'sets' must map"):
        LearnedPolicy(arrays, {**meta, "sets": [["dynamic_obstacles"]]})
    with pytest.raises(PolicyFileError, match="must list its observation keys"):
        LearnedPolicy(arrays, {**meta, "sets": {"movers": "dynamic_obstacles", "statics": ["static_obstacles"]}})
    with pytest.raises(PolicyFileError, match="more than once"):
        LearnedPolicy(arrays, {**meta, "sets": {"movers": meta["sets"]["movers"],
                                                "statics": ["static_obstacles", "dynamic_size"]}})
    with pytest.raises(PolicyFileError, match="no row per obstacle"):
        LearnedPolicy(arrays, {**meta, "observation_shapes": {**meta["observation_shapes"], "static_obstacles": []}})
    with pytest.raises(PolicyFileError, match=r"are set encoders.*\['movers'\]"):
        LearnedPolicy({k: v for k, v in arrays.items() if k != "statics.w0"} | {"statics.w9": arrays["statics.w0"]},
                      {**meta, "sets": {"movers": meta["sets"]["movers"]}})
    with pytest.raises(PolicyFileError, match="are set encoders"):
        LearnedPolicy(arrays, {**meta, "format": "deck_sim.actor/1"})
    with pytest.raises(PolicyFileError, match="name different keys"):
        LearnedPolicy(arrays, {**meta, "observation_keys": meta["observation_keys"][:-1]})
    # the shapes' record in another order changes nothing: the flat vector follows observation_keys
    shuffled = {**meta, "observation_shapes": dict(reversed(list(meta["observation_shapes"].items())))}
    x = np.random.default_rng(3).normal(0.0, 10.0, size=(5, agent.obs_dim))
    np.testing.assert_array_equal(LearnedPolicy(arrays, shuffled).act_flat(x), LearnedPolicy(arrays, meta).act_flat(x))


def test_set_actor_config_errors_name_the_field(shapes):
    with pytest.raises(ConfigError, match="actor_arch"):
        make_config(actor_arch="transformer")
    with pytest.raises(ConfigError, match="set_hidden"):
        make_config(set_hidden=())
    dim = sum(int(np.prod(s)) for s in shapes.values())
    with pytest.raises(ValueError, match="needs the observation's shapes"):
        DDPGAgent(dim, 2, TrainConfig(actor_arch="sets"))
    with pytest.raises(ValueError, match="holds no obstacle set"):
        DDPGAgent(4, 2, TrainConfig(actor_arch="sets"), shapes={"target": (2,), "position": (2,)})


def _short(**fields) -> TrainConfig:  # noqa: ANN003
    """``conftest.short_config`` with the set actor (the movers' sizes in the observation, environments inline)."""
    base = dict(set_hidden=(16, 16), actor_arch="sets", total_steps=100, env_worker=False,
                scene_overrides={"episode__mover_size": True})
    return short_config(**{**base, **fields})


@pytest.mark.slow
def test_a_set_actor_run_resumes_exactly_polishes_and_exports_an_actor_that_acts(tmp_path):
    import deck_sim

    whole = Trainer(_short(polish_epochs=2), tmp_path / "whole", progress=False)
    whole.train()
    broken = Trainer(_short(polish_epochs=2), tmp_path / "broken", progress=False)
    broken.train(stop_at=60)
    Trainer(_short(polish_epochs=2), tmp_path / "broken", resume=True, progress=False).train()
    with np.load(tmp_path / "whole" / "actor.npz") as a, np.load(tmp_path / "broken" / "actor.npz") as b:
        assert "movers.w0" in a.files and "statics.w0" in a.files
        for k in a.files:
            if k != "meta":
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    policy = load_actor(tmp_path / "whole" / "actor.npz")
    assert policy.meta["polished"] and policy.meta["format"] == ACTOR_FORMAT_SETS
    obs = whole.buffer.obs[: whole.buffer.size]
    np.testing.assert_allclose(policy.act_flat(obs), whole.agent.act(obs), atol=1e-5)
    env = deck_sim.load("deck1", seed=0, **policy.scene_overrides)
    action = policy.act(env.reset().observation)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)


def test_an_ensemble_of_set_actors_acts_by_the_mean_of_the_agents_actions(shapes, tmp_path):
    agents = [_agent(shapes, seed=0), _agent(shapes, seed=1)]
    path = EnsemblePolicy([_policy(a) for a in agents]).save(tmp_path / "pair.npz")
    ensemble = load_actor(path)
    assert isinstance(ensemble, EnsemblePolicy)
    assert [m.meta["format"] for m in ensemble.members] == [ACTOR_FORMAT_SETS] * 2
    x = np.random.default_rng(4).normal(3.0, 20.0, size=(40, agents[0].obs_dim))
    expected = (agents[0].act(x) + agents[1].act(x)) / 2
    assert not np.allclose(agents[0].act(x), agents[1].act(x), atol=1e-2)
    np.testing.assert_allclose(ensemble.act_flat(x), expected, atol=1e-5)


def test_a_set_actor_on_a_deck_without_movers_reads_the_statics_alone(tmp_path):
    # no movers: the movers' keys have 0 rows, so the actor has no movers' encoder (a max over no mover would be
    # undefined); a set asked to hold no obstacle is refused by name
    env = make_env("deck1", "mpc", episode__mover_size=True, **NEAR)
    shapes = env_layout(env).shapes
    env.close()
    assert shapes["dynamic_obstacles"] == (0, 2)
    assert obstacle_sets(shapes) == {"statics": ["static_obstacles"]}
    with pytest.raises(ValueError, match="set 'movers' holds no obstacle"):
        set_indices(shapes, {"movers": ["dynamic_obstacles", "predicted"]})
    cfg = _short(total_steps=60, scene_overrides={"episode__mover_size": True, **NEAR})
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    trainer.train()
    policy = load_actor(tmp_path / "run" / "actor.npz")
    assert policy.sets == {"statics": ["static_obstacles"]} and "movers.w0" not in policy.arrays
    obs = trainer.buffer.obs[: trainer.buffer.size]
    np.testing.assert_allclose(policy.act_flat(obs), trainer.agent.act(obs), atol=1e-5)


def test_the_set_actors_preactivation_is_its_action_before_tanh(shapes):
    agent = _agent(shapes)
    x = agent.norm(torch.as_tensor(np.random.default_rng(2).normal(3.0, 20.0, size=(20, agent.obs_dim)),
                                   dtype=torch.float32))
    with torch.no_grad():
        torch.testing.assert_close(torch.tanh(agent.actor.preactivation(x)), agent.actor(x))
