"""Training runs on real scenes (``training.loop.Trainer``): determinism, learning beats random on a simple deck,
the curriculum, the logs (CSV and TensorBoard), the exported actor files and the ``deck-sim train`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import NEAR
from conftest import short_config as _short
from training_runs import assert_same_run, csv_rows

from training.config import TrainConfig
from training.envs import FAR
from training.loop import EVAL_FIELDS, PROGRESS_FIELDS, Trainer, load_checkpoint


def test_a_run_observes_its_forecast_and_its_actor_asks_for_it(tmp_path):
    from deck_sim.policies import LearnedPolicy

    t = Trainer(_short(total_steps=20, demo_episodes=0, pretrain_updates=0, learning_starts=10, bc_weight=0.0,
                       expert_relabel=False, forecast="constant_velocity"), tmp_path / "r", progress=False)
    t.train()
    policy = LearnedPolicy.load(tmp_path / "r" / "actor.npz")
    assert policy.predictor == "constant_velocity"
    assert policy.scene_overrides["episode__predictor"] == "constant_velocity"
    assert json.loads((tmp_path / "r" / "config.json").read_text())["forecast"] == "constant_velocity"


@pytest.mark.slow
def test_two_seeded_runs_give_identical_losses_and_actions(tmp_path):
    """...and it makes no difference whether the environments step in a worker process or inline."""
    a = Trainer(_short(env_worker=True), tmp_path / "a", progress=False)
    a.train()
    b = Trainer(_short(env_worker=False), tmp_path / "b", progress=False)
    b.train()
    assert_same_run(a, b)


@pytest.mark.slow
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


@pytest.mark.slow
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
    from training.checkpoints import CheckpointError, check_compatible

    with pytest.raises(CheckpointError, match="total_steps: checkpoint 60, now 120"):  # the stages would move
        check_compatible(TrainConfig.from_dict({**config, "total_steps": 120}), config, tmp_path / "c")
    check_compatible(TrainConfig.from_dict({**config, "curriculum": [], "total_steps": 120}),
                     {**config, "curriculum": []}, tmp_path / "c")  # without one a run may go on longer


@pytest.mark.slow
def test_the_normaliser_leaves_out_the_rows_a_curriculum_stage_pads(tmp_path):
    from training.config import CurriculumStage

    stages = (CurriculumStage(until=0.5, max_target_distance=60.0, movers=2),)  # 2 of deck 1's 5 movers
    t = Trainer(_short(total_steps=48, demo_episodes=0, pretrain_updates=0, curriculum=stages,
                       scene_overrides={"episode__time_limit": 3.0}), tmp_path / "n", progress=False)
    t.train()  # 6-step episodes: the second half of the run plays the whole scene
    rows = t.buffer.obs[: t.buffer.size].reshape(t.buffer.size, -1)
    dyn = t.layout.slices()["dynamic_obstacles"]
    movers = rows[:, dyn].reshape(len(rows), 5, 2)
    real = ~np.all(movers == FAR, axis=2)  # (rows, movers): a mover that took part
    assert real[:, :2].all() and 0 < real[:, 2:].sum() < real[:, 2:].size
    count = t.agent.norm.count.numpy()[dyn].reshape(5, 2)
    np.testing.assert_allclose(count, np.repeat(real.sum(0)[:, None], 2, axis=1) + 1e-4)
    np.testing.assert_allclose(t.agent.norm.count.numpy()[t.layout.slices()["target"]], len(rows) + 1e-4)
    mean = t.agent.norm.mean.numpy()[dyn].reshape(5, 2)
    for k in range(5):  # each mover row's mean is that of the real movers it held alone
        np.testing.assert_allclose(mean[k], movers[real[:, k], k].mean(0), rtol=1e-4, atol=1e-3)
    assert np.abs(mean).max() < FAR / 4


@pytest.mark.slow
def test_exported_actor_acts_like_the_agent(tmp_path):
    from deck_sim.policies import LearnedPolicy

    t = Trainer(
        _short(total_steps=40, demo_episodes=1, pretrain_updates=10, obs_norm=True), tmp_path / "r", progress=False
    )
    t.train()
    policy = LearnedPolicy.load(tmp_path / "r" / "actor.npz")
    obs = t.buffer.obs[: t.buffer.size]
    np.testing.assert_allclose(policy.act_flat(obs), t.agent.act(obs), atol=1e-5)


@pytest.mark.slow
def test_an_actor_file_asks_for_the_observation_options_it_was_trained_with(tmp_path):
    import deck_sim
    from deck_sim.policies import LearnedPolicy, PolicyFileError
    from deck_sim.scenes import SceneSpecError

    overrides = {
        "episode__predicted_frame": "mover",
        "episode__mover_size": True,
        "episode__near_steps": 2,
        "episode__near_obstacles": True,
        "episode__predicted_near": True,
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
    assert "static_near" in policy.keys and "dynamic_near" in policy.keys and "predicted_near" in policy.keys
    assert policy.shapes["route"] == (3, 2)
    # an actor whose near field came from its scene file asks for no range; a scene without one is refused
    del policy.meta["scene_overrides"]["episode__near_steps"]
    assert "episode__near_steps" not in policy.scene_overrides
    with pytest.raises(SceneSpecError, match="near_obstacles: needs a near field"):  # its near obstacles need one
        deck_sim.load("deck1", seed=0, **{**policy.scene_overrides, "episode__predicted_near": False})
    with pytest.raises(SceneSpecError, match="predicted_near: needs a near field"):  # and so does its near forecast
        deck_sim.load("deck1", seed=0, **{**policy.scene_overrides, "episode__near_obstacles": False})
    overrides = {k: v for k, v in policy.scene_overrides.items()
                 if k not in ("episode__near_obstacles", "episode__predicted_near")}
    env = deck_sim.load("deck1", seed=0, **overrides)
    with pytest.raises(PolicyFileError, match="needs observation 'target_near'"):
        policy.flatten(env.reset().observation)


@pytest.mark.slow
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


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["deck1", "deck2", "square"])
def test_the_shipped_policies_load_and_act_on_their_scene(scene):
    import deck_sim
    from deck_sim.policies import EnsemblePolicy, load_actor, make_policy, policy_overrides, shipped_policy_path

    path = shipped_policy_path("mddpg", scene)
    shipped = load_actor(path)
    members = len(shipped.members) if isinstance(shipped, EnsemblePolicy) else 1
    assert path.stat().st_size < members * 1.25 * 1024 * 1024  # small: weights only, no buffer or optimiser state
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


@pytest.mark.slow
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


def _scalars(run_dir) -> dict[str, list[tuple[int, float]]]:  # noqa: ANN001
    """Every TensorBoard scalar of a run folder's ``tb/``: tag -> [(step, value)] as TensorBoard shows them."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir / "tb"))
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


@pytest.mark.slow
def test_tensorboard_gets_every_logged_column_and_the_step_0_evaluation(tmp_path):
    """Every column of ``progress.csv`` and ``eval.csv`` but the step is a TensorBoard scalar at its row's step, the
    evaluation after the demonstrations (step 0) included; a resumed run keeps what was logged up to its
    checkpoint."""
    cfg = _short(
        algo="ddpg", total_steps=20, num_envs=1, env_worker=False, learning_starts=4, eval_every=10, log_every=10
    )
    Trainer(cfg, tmp_path / "r", progress=False).train(stop_at=10)
    Trainer(cfg, tmp_path / "r", resume=True, progress=False).train()
    scalars = _scalars(tmp_path / "r")
    progress, evals = csv_rows(tmp_path / "r" / "progress.csv"), csv_rows(tmp_path / "r" / "eval.csv")
    assert [r["step"] for r in progress] == ["10", "20"] and [r["step"] for r in evals] == ["0", "10", "20"]
    for prefix, fields, rows in (("train", PROGRESS_FIELDS, progress), ("eval", EVAL_FIELDS, evals)):
        for k in fields[1:]:
            assert [step for step, _ in scalars[f"{prefix}/{k}"]] == [int(r["step"]) for r in rows], k
            if k not in ("wall_s", "sps"):  # (csv_rows leaves out the wall-clock columns)
                want = [float(r[k]) for r in rows]
                np.testing.assert_allclose([v for _, v in scalars[f"{prefix}/{k}"]], want, rtol=1e-6, err_msg=k)
    assert {"train/bc_loss", "train/noise_sigma", "eval/success"} <= set(scalars)
    assert scalars["eval/success"][0][0] == 0
