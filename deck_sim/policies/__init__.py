"""Policies with the ``act(observation) -> action`` interface: references that need no training, and learned ones.

``scripted`` plans with full knowledge of the scene through the task's ``planner_view`` (it plans around the
observation's predicted mover positions: the ``oracle`` predictor shows it the movers' true future, ``mpc`` the MPC
forecast); ``apf``, ``astar`` and ``mpc`` are the classical references of ``deck_sim.control.planners`` on the same
view (the evaluation runs them with the MPC predictor); ``random`` and ``zero`` are references (``reference``).
``LearnedPolicy`` runs an actor exported by ``training`` (``deck-sim train``) from a weights-only ``.npz`` file with
numpy alone, ``EnsemblePolicy`` several such actors by the mean of their actions (``actors``); ``mddpg``, ``ddpg``,
``dqn`` and ``a2c`` name the policies shipped in ``deck_sim/trained/`` for the environment's scene (``registry``;
the names are ``deck_sim.agents``'s). ``PrioritisedPolicy`` and ``IndependentPolicy`` act for every aircraft of a
multi-aircraft scene at once, ``SharedPolicy`` runs a single-agent policy for each, and ``make_team_policy`` picks
one by name (``team``).
"""

from deck_sim.policies.actors import (
    ACTIVATIONS,
    ACTOR_FORMAT,
    ACTOR_FORMAT_SETS,
    ACTOR_FORMAT_V2,
    CRITIC_PREFIX,
    ENSEMBLE_FORMAT,
    HEADS,
    OBSTACLE_SETS,
    SELECT_OFFSETS,
    EnsemblePolicy,
    LearnedPolicy,
    PolicyFileError,
    load_actor,
    obstacle_sets,
    selecting,
    set_indices,
    write_actor_file,
)
from deck_sim.policies.reference import TEACHER_VIEWS, Policy, RandomPolicy, ScriptedPolicy, ZeroPolicy
from deck_sim.policies.registry import (
    CLASSICAL,
    POLICY_NAMES,
    REFERENCE_PREDICTOR,
    SCRIPTED,
    SHIPPED_ALGOS,
    TRAINED_DIR,
    make_policy,
    policy_file,
    policy_overrides,
    seeds_text,
    shipped_log_dir,
    shipped_logs,
    shipped_policy_path,
)
from deck_sim.policies.team import (
    TEAM_PLANNERS,
    IndependentPolicy,
    PrioritisedPolicy,
    SharedPolicy,
    TeamPolicy,
    make_team_policy,
    nearest_dynamic,
    team_policy_overrides,
)

__all__ = [
    "ACTIVATIONS",
    "ACTOR_FORMAT",
    "ACTOR_FORMAT_SETS",
    "ACTOR_FORMAT_V2",
    "CLASSICAL",
    "CRITIC_PREFIX",
    "ENSEMBLE_FORMAT",
    "HEADS",
    "TEAM_PLANNERS",
    "OBSTACLE_SETS",
    "POLICY_NAMES",
    "REFERENCE_PREDICTOR",
    "SCRIPTED",
    "SELECT_OFFSETS",
    "SHIPPED_ALGOS",
    "TRAINED_DIR",
    "EnsemblePolicy",
    "IndependentPolicy",
    "LearnedPolicy",
    "Policy",
    "PolicyFileError",
    "PrioritisedPolicy",
    "RandomPolicy",
    "ScriptedPolicy",
    "SharedPolicy",
    "TEACHER_VIEWS",
    "TeamPolicy",
    "ZeroPolicy",
    "load_actor",
    "make_policy",
    "make_team_policy",
    "nearest_dynamic",
    "obstacle_sets",
    "policy_file",
    "policy_overrides",
    "seeds_text",
    "selecting",
    "set_indices",
    "shipped_log_dir",
    "shipped_logs",
    "shipped_policy_path",
    "team_policy_overrides",
    "write_actor_file",
]
