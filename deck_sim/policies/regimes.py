"""What a learned agent learnt from: its training regime, read from its training config or its actor file.

Three regimes, named the same way in training configs, run folders, actor files, ``deck-sim run`` and every results
table:

- ``reward``: reinforcement learning from the scene's reward alone (paper eq. 10-16): no demonstrations, no planner
  labels, no cloning term, no final fit. The paper's protocol.
- ``planner``: also learns from a planner that sees only what the agent's observation holds: the scripted planner
  on ``Navigate.observed_view`` (``TrainConfig.teacher_view = "observation"``): the observed footprints of every
  obstacle, and the observed MPC forecast for MDDPG, none for DDPG.
- ``oracle-teacher``: also learns from the scripted planner (``TrainConfig``'s teaching fields), which reads the
  task's full state (``Navigate.planner_view``: every obstacle's exact footprint and heading, the aircraft's body
  and limits) and plans around the MPC forecast (``training.envs.TEACHER_PREDICTOR``), through demonstrations,
  labels, a cloning term or a final fit.

A config teaches when any of its teaching fields is on (``TEACHING_FIELDS``), and its teacher is the scripted planner.
Numpy and the standard library only: reading a regime needs no torch.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

REGIMES = ("reward", "planner", "oracle-teacher")
"""The training regimes, from the least to the most information."""

REGIME_TEXT = {
    "reward": "the reward alone",
    "planner": "the labels of a planner that sees what the agent sees",
    "oracle-teacher": "the labels of the scripted planner, which reads the task's full state",
}
"""What each regime means, for tables and messages."""

TEACHING_FIELDS = (
    "demo_episodes",
    "expert_relabel",
    "bc_weight",
    "pretrain_updates",
    "polish_epochs",
    "dagger_steps",
)
"""``TrainConfig`` fields that, when non-zero, let a planner's actions into training: demonstrations in the replay
buffer, the planner's label of every visited state, the cloning term, pre-training on the demonstrations, the final
cloning fit and its DAgger round."""


def config_regime(config: Mapping[str, Any]) -> str:
    """The regime of a training config given as a mapping (``TrainConfig.to_dict()`` or a run's ``config.json``):
    ``reward`` if no teaching field is on, else ``planner`` if its teacher reads the observation alone
    (``teacher_view``), else ``oracle-teacher``."""
    if not any(bool(config.get(name) or 0) for name in TEACHING_FIELDS):
        return "reward"
    return "planner" if config.get("teacher_view", "full") == "observation" else "oracle-teacher"


def actor_regime(meta: Mapping[str, Any]) -> str | None:
    """The regime recorded in an actor file's record (``LearnedPolicy.meta``): its ``regime`` field, else the one
    its training ``config`` makes; a stable-baselines3 export (no config of DDPG's kind) learnt from the reward.
    An ensemble's is its members' if they agree. None if the record does not tell.
    """
    recorded = meta.get("regime")
    if recorded in REGIMES:
        return str(recorded)
    members = meta.get("members")
    if isinstance(members, list) and members:
        regimes = {actor_regime(m) if isinstance(m, Mapping) else None for m in members}
        return regimes.pop() if len(regimes) == 1 else None
    config = meta.get("config")
    if isinstance(config, Mapping):
        if meta.get("algo") in ("dqn", "a2c"):  # stable-baselines3 learns from the environment's reward alone
            return "reward"
        return config_regime(config)
    return None


def regime_text(regime: str | None) -> str:
    """``regime`` for a table cell or a message: its meaning and its name, or ``an unrecorded regime``."""
    if regime is None:
        return "an unrecorded regime"
    return f"{REGIME_TEXT[regime]} (regime: {regime})"
