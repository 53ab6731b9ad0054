"""The Gymnasium adapter: registration, the env checker, seeding, termination versus truncation."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import deck_sim.wrappers  # noqa: F401 - registers the ids
from deck_sim.wrappers import GYM_IDS, DeckSimEnv


@pytest.mark.parametrize("scene", ["deck1", "square"])
def test_passes_gymnasiums_env_checker(scene):
    env = DeckSimEnv(scene)
    check_env(env, skip_render_check=True)
    assert env.observation_space.dtype == np.float32 and env.action_space.shape == (2,)


def test_registered_ids_make_environments():
    for gym_id in GYM_IDS.values():
        assert gym_id in gymnasium.registry
    env = gymnasium.make("deck_sim/Deck1-v0")
    obs, info = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape and "position" in info
    env.close()


def test_same_seed_same_episode_and_termination_semantics():
    env = DeckSimEnv("deck1", episode__time_limit=5.0)
    a, _ = env.reset(seed=9)
    b, _ = env.reset(seed=9)
    np.testing.assert_array_equal(a, b)
    done = False
    steps = 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        steps += 1
        done = terminated or truncated
    assert truncated and not terminated and steps == 10  # 5 s at 0.5 s a step, standing still
    assert np.isfinite(reward)
