"""Test configuration: no rendering in the test process (render tests run the CLI in a subprocess), and the
property tests' examples drawn from a fixed seed (hypothesis ``derandomize``), so that every run of the suite, CI's
included, tries the same cases; ``HYPOTHESIS_PROFILE=explore`` draws new ones, to look for failures by hand."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

SCENES = ("deck1", "deck2", "square")
NEAR = {  # scene fields of an empty deck 1 (no movers, only the island) with a near target: a short run learns it
    "static__slotted": 0,
    "movers__tractors": 0,
    "movers__aircraft": 0,
    "agent__start_sites": ["start_5"],
    "agent__target_sites": ["start_1", "start_2"],  # 18-22 m ahead of the start
    "agent__min_target_distance": 10.0,
    "agent__max_target_distance": 30.0,
}


@pytest.fixture(scope="session")
def envs():
    """One environment per scene, built once (construction costs about a second)."""
    import deck_sim

    return {name: deck_sim.load(name, seed=0) for name in SCENES}


def run_steps(env, n, actions=None, seed=0):
    """Reset and step ``env`` n times with seeded random actions; return (observations, rewards)."""
    rng = np.random.default_rng(seed)
    ts = env.reset()
    obs, rewards = [ts.observation], []
    for i in range(n):
        a = actions[i] if actions is not None else rng.uniform(-1, 1, 2)
        ts = env.step(a)
        obs.append(ts.observation)
        rewards.append(ts.reward)
        if ts.last():
            ts = env.reset()
            obs.append(ts.observation)
    return obs, rewards


def short_config(**fields):  # noqa: ANN003, ANN201
    """A seconds-long run of the tuned recipe on deck 1 (tiny networks, two environments stepped in the test's own
    process: a test of the worker process asks for ``env_worker=True``), ``fields`` on top."""
    base = dict(
        scene="deck1",
        total_steps=120,
        num_envs=2,
        env_worker=False,
        hidden=(32, 32),
        batch_size=32,
        learning_starts=40,
        demo_episodes=1,
        pretrain_updates=5,
        eval_every=0,
        eval_episodes=1,
        log_every=20,
        checkpoint_every=0,
        updates_per_step=0.5,
    )
    base.update(fields)
    from training.config import make_config

    return make_config("tuned", **base)
