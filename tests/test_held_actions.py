"""Held actions (``hold_prob``): an environment now and then takes one fixed action for several steps in place of
the actor's (stop and wait, or one random action), the replay buffer stores what was done, and a run with them
resumes exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import short_config
from tests.training_runs import assert_same_run
from training import checkpoints
from training.checkpoints import load_checkpoint
from training.config import ConfigError, arm_config, make_config
from training.loop import Trainer
from training.noise import HeldActions


@settings(max_examples=40, deadline=None)
@given(
    prob=st.floats(0.01, 1.0),
    max_steps=st.integers(1, 12),
    action=st.sampled_from(["stop", "random"]),
    seed=st.integers(0, 2**16),
)
def test_each_hold_keeps_one_action_for_at_most_max_steps(prob, max_steps, action, seed):
    hold, rng = HeldActions(3, 2, prob, max_steps, action), np.random.default_rng(seed)
    rows = []
    for _ in range(200):
        rows.append(hold.sample(rng))
        assert np.all((hold.left >= 0) & (hold.left < max_steps))  # a hold lasts at most max_steps, this one included
    rows = np.stack(rows)  # (steps, envs, 2)
    for env in range(3):
        held = np.isfinite(rows[:, env, 0])
        assert np.array_equal(held, np.isfinite(rows[:, env, 1]))
        values = rows[held, env]
        if action == "stop":
            assert np.all(values == 0.0)
            continue
        assert np.all(np.abs(values) <= 1.0)
        # one random action per hold (two holds in a row differ almost surely): no run of it outlasts max_steps
        run = 0
        for t in range(len(rows)):
            same = t > 0 and held[t] and held[t - 1] and np.array_equal(rows[t, env], rows[t - 1, env])
            run = run + 1 if same else int(held[t])
            assert run <= max_steps
    if prob == 1.0:  # every step of every environment is held
        assert np.isfinite(rows).all()


def test_holds_start_at_their_rate_last_their_length_and_end_with_the_episode():
    hold, rng = HeldActions(4, 2, 0.05, 9, "random"), np.random.default_rng(0)
    rows = np.stack([hold.sample(rng) for _ in range(20_000)])
    held = np.isfinite(rows[:, :, 0])
    lengths, starts = [], 0
    for env in range(4):
        run = 0
        for t in range(len(held)):
            changed = t == 0 or not held[t - 1, env] or not np.array_equal(rows[t, env], rows[t - 1, env])
            new = held[t, env] and changed
            if new:
                starts += 1
                if run:
                    lengths.append(run)
                run = 1
            elif held[t, env]:
                run += 1
            elif run:
                lengths.append(run)
                run = 0
    assert lengths and max(lengths) <= 9 and min(lengths) >= 1
    assert abs(np.mean(lengths) - 5.0) < 0.3  # uniform on 1..9
    # a hold starts with probability 0.05 on each step that a hold still running does not take: the steps not
    # held and the first steps of holds
    free = (~held).sum() + starts
    assert abs(starts / free - 0.05) < 0.004
    hold.left[:] = 3
    hold.reset(2)
    assert list(hold.left) == [3, 3, 0, 3]


def test_without_holds_no_random_number_is_drawn():
    rng = np.random.default_rng(7)
    before = rng.bit_generator.state
    assert HeldActions(2, 2, 0.0, 5).sample(rng) is None
    assert rng.bit_generator.state == before  # runs without holds draw as they did before holds existed


def test_hold_settings_are_checked():
    for field, value, match in (
        ("hold_prob", 1.5, "hold_prob"),
        ("hold_prob", -0.1, "hold_prob"),
        ("hold_steps", 0, "hold_steps"),
        ("hold_steps", 2.5, "hold_steps"),
        ("hold_action", "brake", "hold_action"),
    ):
        with pytest.raises(ConfigError, match=match):
            make_config("reward", **{field: value})
    cfg = arm_config("reward-mddpg-with-wait", "deck1", 1000, 0)
    assert (cfg.hold_prob, cfg.hold_action) == (0.02, "stop") and cfg.regime == "reward"
    assert arm_config("reward-ddpg-with-ez", "deck1", 1000, 0).hold_action == "random"


@pytest.mark.slow
def test_a_run_with_held_stops_stores_them_and_resumes_exactly(tmp_path):
    cfg = short_config(  # (the environments in the worker process: held rows go through its pipe)
        demo_episodes=0, pretrain_updates=0, bc_weight=0.0, expert_relabel=False, hold_prob=0.2, hold_steps=4,
        noise_sigma=0.3, noise_sigma_final=0.3, env_worker=True,
    )
    whole = Trainer(cfg, tmp_path / "whole", progress=False)
    whole.train()
    acted = whole.buffer.action[cfg.learning_starts : whole.buffer.size]
    stops = np.all(acted == 0.0, axis=1)
    # with sigma 0.3 noise an action of exactly (0, 0) comes only from a hold; about a fifth of the steps are held
    assert 0.1 < stops.mean() < 0.6
    first = Trainer(cfg, tmp_path / "broken", progress=False)
    first.train(stop_at=70)
    assert first.hold.left.any()  # the checkpoint is taken in the middle of a hold
    resumed = Trainer(cfg, tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
    # a checkpoint written before held actions existed has no "hold": such a run resumes with none in progress
    old = tmp_path / "old"
    Trainer(cfg, old, progress=False).train(stop_at=70)
    state = load_checkpoint(old / "checkpoint.pt")
    del state["hold"]
    checkpoints._write(state, old / "checkpoint.pt")
    resumed_old = Trainer(cfg, old, resume=True, progress=False)
    assert not resumed_old.hold.left.any()
    resumed_old.train()
    assert resumed_old.step == whole.step


def test_an_environment_group_takes_the_held_rows_as_they_are_and_the_others_from_the_policy():
    from training.runners import EnvGroup, EnvSpec, StepOrder

    group = EnvGroup(3, None)
    try:
        for i in range(3):
            group.build(i, *EnvSpec("deck1", "none", {}, False))
            group.reset(i, 100 + i)
        order = StepOrder(
            noise=np.full((3, 2), 0.25),
            policy=lambda obs: np.full((len(obs), 2), 0.5),
            hold=np.array([[np.nan, np.nan], [0.0, 0.0], [-0.7, 0.3]]),
        )
        assert np.array_equal(order.rows(1, 3).hold, order.hold[1:3], equal_nan=True)  # each worker gets its rows
        actions = [res.action for res in group.step(order, order.policy)]
        np.testing.assert_allclose(actions, [[0.75, 0.75], [0.0, 0.0], [-0.7, 0.3]])
    finally:
        group.close()
