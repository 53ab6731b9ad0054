"""The stable-baselines3 baselines (``training.baselines``): DQN and A2C train, evaluate and resume, and their
config (``DQNConfig``, ``A2CConfig``) is checked before a run starts and saved with it."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from training_runs import csv_rows


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_sb3_baselines_train_evaluate_and_resume(tmp_path, algo):
    from training.baselines import discrete_actions, load_baseline, train_baseline

    out = tmp_path / algo
    kwargs = {"learning_starts": 20, "buffer_size": 1000} if algo == "dqn" else {"n_steps": 8}
    summary = train_baseline(
        algo, "deck1", 48, 0, out, progress=False, eval_every=0, eval_episodes=1, log_every=16, **kwargs
    )
    assert summary["step"] == 48 and summary["eval"]["episodes"] == 1
    assert len(csv_rows(out / "progress.csv")) == 3 and len(csv_rows(out / "eval.csv")) == 1
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


@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_ctrl_c_stops_a_baseline_run_with_its_model_saved_and_resume_finishes_it(tmp_path, algo, monkeypatch):
    """Ctrl-C during learning (here raised from the 40th environment step) stops the run after that step: the
    model and its normalisation are saved whole, no actor is exported, and ``resume`` trains on to the end."""
    import signal

    from deck_sim.wrappers import DeckSimEnv
    from training.baselines import load_baseline, train_baseline

    out = tmp_path / algo
    kwargs = {"learning_starts": 20, "buffer_size": 1000} if algo == "dqn" else {"n_steps": 8}
    real_step, calls = DeckSimEnv.step, []

    def step_then_ctrl_c(self, action):  # noqa: ANN001, ANN202
        calls.append(1)
        if len(calls) == 40:
            signal.raise_signal(signal.SIGINT)
        return real_step(self, action)

    monkeypatch.setattr(DeckSimEnv, "step", step_then_ctrl_c)
    before = signal.getsignal(signal.SIGINT)  # (SIG_IGN where pytest itself was started in the background)
    stopped = train_baseline(
        algo, "deck1", 400, 0, out, progress=False, eval_every=0, eval_episodes=1, log_every=16, **kwargs
    )
    monkeypatch.undo()
    assert stopped["stopped"] and 40 <= stopped["step"] < 400
    assert not (out / "actor.npz").exists() and not list(out.glob("*.tmp*"))
    assert load_baseline(out) is not None
    assert signal.getsignal(signal.SIGINT) is before  # (the handler is given back)
    if algo == "dqn":  # the replay buffer is saved with the model: every step taken but the one the stop came
        # in (SB3 ends its rollout before storing that step's transition)
        from stable_baselines3 import DQN

        model = DQN.load(str(out / "model.zip"))
        model.load_replay_buffer(str(out / "replay_buffer.pkl"))
        assert model.replay_buffer.size() == stopped["step"] - 1
        saved = model.replay_buffer.observations[: stopped["step"] - 1].copy()
    clock = json.loads((out / "clock.json").read_text())  # the stopped run's clock, counted on when resumed
    assert clock["step"] == stopped["step"] and clock["wall_s"] > 0
    done = train_baseline(algo, "deck1", 400, 0, out, resume=True, progress=False, eval_every=0, eval_episodes=1)
    assert not done["stopped"] and done["step"] == 400 and (out / "actor.npz").exists()
    with open(out / "eval.csv", newline="") as f:
        final = float(list(csv.DictReader(f))[-1]["wall_s"])  # (no periodic evaluation before it)
    assert clock["wall_s"] < final <= clock["wall_s"] + done["wall_s"]
    if algo == "dqn":  # the resumed run learnt on from the saved buffer: it holds those rows and the new ones
        model.load_replay_buffer(str(out / "replay_buffer.pkl"))
        assert model.replay_buffer.size() == 399
        np.testing.assert_array_equal(model.replay_buffer.observations[: len(saved)], saved)


def test_the_baseline_config_names_a_bad_field_before_any_run_folder_is_made(tmp_path):
    from training.baselines import A2CConfig, DQNConfig, baseline_config, train_baseline
    from training.config import ConfigError

    out = tmp_path / "run"
    for overrides, field in (
        ({"learning_rate": "fast"}, "learning_rate"),
        ({"buffer_size": 1.5}, "buffer_size"),
        ({"n_steps": 8}, "n_steps"),  # an A2C field, not DQN's
        ({"eval_every": -1}, "eval_every"),
        ({"exploration_fraction": 2.0}, "exploration_fraction"),
        ({"net_arch": [64, 0]}, "net_arch"),
        ({"total_steps": 100}, "total_steps"),  # given by the steps argument
    ):
        with pytest.raises(ConfigError, match=field):
            train_baseline("dqn", "deck1", 64, 0, out, progress=False, **overrides)
        assert not out.exists()
    with pytest.raises(ConfigError, match="unknown dqn config field"):
        train_baseline("dqn", "deck1", 64, 0, out, progress=False, learning_rates=1e-3)
    with pytest.raises(ConfigError, match="use_rms_prop: expected true or false"):
        baseline_config("a2c", use_rms_prop=1)
    with pytest.raises(ConfigError, match="seed"):
        baseline_config("a2c", seed=5_000)
    with pytest.raises(ConfigError, match="algo"):
        baseline_config("ppo")
    assert not out.exists()
    dqn = baseline_config("dqn", learning_rate=1, net_arch=[64, 64])
    assert isinstance(dqn, DQNConfig) and dqn.learning_rate == 1.0 and isinstance(dqn.learning_rate, float)
    assert dqn.net_arch == (64, 64) and dqn.sb3_kwargs()["learning_starts"] == 2_000
    assert DQNConfig.from_dict(dqn.to_dict()) == dqn
    a2c = baseline_config("a2c")
    assert isinstance(a2c, A2CConfig) and a2c.sb3_kwargs()["n_steps"] == 16
    with pytest.raises(ConfigError, match="algo: this is a dqn config"):
        DQNConfig.from_dict(a2c.to_dict())


@pytest.mark.slow
def test_a_resumed_baseline_runs_clock_starts_where_its_model_was_saved(tmp_path):
    from training.baselines import CLOCK_FILE, wall_at_save

    rows = [{"step": "50", "wall_s": "10.0"}]
    assert wall_at_save(tmp_path, 80, rows) == 10.0  # no clock: the last evaluation's
    assert wall_at_save(tmp_path, 80, []) == 0.0
    (tmp_path / CLOCK_FILE).write_text(json.dumps({"step": 80, "wall_s": 17.5}))
    assert wall_at_save(tmp_path, 80, rows) == 17.5
    assert wall_at_save(tmp_path, 96, rows) == 10.0  # a clock of another step is not this model's
    (tmp_path / CLOCK_FILE).write_text("{not json")
    assert wall_at_save(tmp_path, 80, rows) == 10.0


def test_a_baseline_run_saves_its_config_and_resumes_a_run_of_the_step_count_format(tmp_path):
    """``config.json`` holds every field of the run's config; a run folder whose ``config.json`` gives the run's
    length as ``steps`` (and its SB3 keywords under ``sb3``) resumes, its actor's record giving ``total_steps``."""
    import json

    from deck_sim.policies import LearnedPolicy
    from training.baselines import DQNConfig, train_baseline

    out = tmp_path / "dqn"
    train_baseline("dqn", "deck1", 32, 0, out, progress=False, eval_every=0, eval_episodes=1, learning_starts=20,
                   buffer_size=1000)
    saved = json.loads((out / "config.json").read_text())
    assert DQNConfig.from_dict(saved) == DQNConfig(
        total_steps=32, eval_every=0, eval_episodes=1, learning_starts=20, buffer_size=1000
    )
    assert LearnedPolicy.load(out / "actor.npz").meta["config"] == saved
    old = {"algo": "dqn", "predictor": "none", "sb3": {"buffer_size": 1000, "learning_starts": 20},
           "scene": "deck1", "scene_overrides": {}, "seed": 0, "steps": 32}
    (out / "config.json").write_text(json.dumps(old))
    train_baseline("dqn", "deck1", 48, 0, out, resume=True, progress=False, eval_every=0, eval_episodes=1)
    meta = LearnedPolicy.load(out / "actor.npz").meta
    assert meta["trained_steps"] == 48 and meta["config"]["seed"] == 0 and "total_steps" in meta["config"]


@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_a_baseline_steps_several_environments_each_on_its_own_episode_stream(tmp_path, algo):
    """With ``num_envs`` environments the run's steps count every environment's transitions, logging and
    evaluation fire when the count passes each period, and environment ``i`` plays
    ``train_episode_seed(seed, i, k)``."""
    from training.baselines import SeededEpisodes, train_baseline
    from training.config import train_episode_seed

    out = tmp_path / algo
    kwargs = {"learning_starts": 20, "buffer_size": 1000} if algo == "dqn" else {"n_steps": 4}
    summary = train_baseline(
        algo, "deck1", 48, 0, out, progress=False, num_envs=3, eval_every=30, eval_episodes=1, log_every=16, **kwargs
    )
    assert summary["step"] == 48
    assert [int(r["step"]) for r in csv_rows(out / "progress.csv")] == [18, 33, 48]
    assert [int(r["step"]) for r in csv_rows(out / "eval.csv")] == [30, 48]
    from deck_sim.wrappers import DeckSimEnv

    first = []
    for stream in range(2):
        obs, _ = SeededEpisodes(DeckSimEnv("deck1", episode__predictor="none"), 0, stream).reset()
        expected, _ = DeckSimEnv("deck1", episode__predictor="none").reset(seed=train_episode_seed(0, stream, 0))
        np.testing.assert_array_equal(obs, expected)
        first.append(obs)
    assert not np.array_equal(first[0], first[1])


def test_a_damaged_dqn_replay_buffer_is_refused_by_name_and_left_in_place(tmp_path):
    from training.baselines import train_baseline
    from training.checkpoints import CheckpointError

    out = tmp_path / "dqn"
    kwargs = {"learning_starts": 20, "buffer_size": 1000}
    train_baseline("dqn", "deck1", 32, 0, out, progress=False, eval_every=0, eval_episodes=1, log_every=16, **kwargs)
    (out / "replay_buffer.pkl").write_bytes(b"not a pickle")
    with pytest.raises(CheckpointError, match=r"replay_buffer.pkl: not a readable replay buffer"):
        train_baseline("dqn", "deck1", 64, 0, out, resume=True, progress=False, eval_every=0, eval_episodes=1)
    assert (out / "replay_buffer.pkl").read_bytes() == b"not a pickle"
