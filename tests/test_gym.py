"""The Gymnasium adapter: registration, the env checker, seeding, termination versus truncation."""

import os
import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import deck_sim.wrappers  # noqa: F401 - registers the ids
from deck_sim.registration import episode_decisions
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


def test_import_deck_sim_alone_registers_the_ids_with_the_scenes_episode_length():
    code = (
        "import deck_sim, gymnasium\n"
        "for scene, gym_id in deck_sim.registration.GYM_IDS.items():\n"
        "    assert gymnasium.spec(gym_id).max_episode_steps == {'deck1': 360, 'deck2': 360, 'square': 300}[scene]\n"
        "env = gymnasium.make('deck_sim/Deck1-v0')\n"
        "env.reset(seed=0)\n"
        "env.close()\n"
        "env.close()\n"
        "print('ok')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "MUJOCO_GL": "disable"})
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_a_full_episode_through_gymnasium_make_truncates_where_the_scene_does():
    env = gymnasium.make("deck_sim/Square-v0", episode__time_limit=4.0)
    assert env.spec.max_episode_steps == 300  # the registered id's own limit: the square's 150 s
    env.reset(seed=5)
    steps, truncated = 0, False
    while not truncated:
        _, _, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
        steps += 1
        assert not terminated
    # the scene's 4 s end first: 9 decisions, the physics clock's sum of 0.025 s steps being just short of 4 s after 8
    assert steps == 9 == episode_decisions(4.0, 0.5, 0.025)
    env.close()
    env.close()
