"""Gymnasium ids of the shipped scenes, registered on ``import deck_sim``.

``gymnasium.make("deck_sim/Deck1-v0")`` then builds ``deck_sim.wrappers.DeckSimEnv`` for that scene, with
Gymnasium's time limit set to the scene's own number of decisions (its time limit over its control period), so
the truncation Gymnasium reports is the scene's.
"""

from __future__ import annotations

GYM_IDS = {"deck1": "deck_sim/Deck1-v0", "deck2": "deck_sim/Deck2-v0", "square": "deck_sim/Square-v0"}
"""Scene name -> Gymnasium id."""


def episode_decisions(time_limit: float, control_period: float, physics_timestep: float) -> int:
    """Decisions in an episode that runs to ``time_limit`` seconds: composer ends it at the first decision after
    which the physics clock, a running sum of ``physics_timestep``, reaches the limit (so a timestep that is not a
    binary fraction, such as 0.025 s, can add a decision)."""
    substeps = round(control_period / physics_timestep)
    clock, decisions = 0.0, 0
    while clock < time_limit:
        for _ in range(substeps):
            clock += physics_timestep
        decisions += 1
    return decisions


def max_episode_steps(scene: str) -> int:
    """Decisions in one episode of ``scene`` that runs to its time limit."""
    from deck_sim.scenes import load_scene

    e = load_scene(scene).episode
    return episode_decisions(e.time_limit, e.control_period, e.physics_timestep)


def register_envs() -> None:
    """Register the Gymnasium id of every shipped scene (idempotent; nothing happens without gymnasium)."""
    try:
        import gymnasium
    except ModuleNotFoundError:
        return
    for scene, gym_id in GYM_IDS.items():
        if gym_id not in gymnasium.registry:
            gymnasium.register(
                id=gym_id,
                entry_point="deck_sim.wrappers:DeckSimEnv",
                kwargs={"scene": scene},
                max_episode_steps=max_episode_steps(scene),
            )
