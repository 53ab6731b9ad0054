"""The one registry of agent names: what ``deck-sim run --policy``, ``deck-sim eval --agents``, the evaluation's
reports and the training configuration accept and how they describe it.

Light on purpose (no MuJoCo, no numpy): the command line reads it to build its help.
"""

from __future__ import annotations

from dataclasses import dataclass

KINDS = ("learned", "classical", "observer", "oracle", "baseline")
"""``learned``: an actor trained by ``deck-sim train`` (shipped per scene in ``deck_sim/trained``);
``classical``: a planner of ``deck_sim.control.planners`` on the MPC predictor's forecast, no training;
``observer``: the scripted planner on what the agent's observation holds alone (no privileged state): the teacher
of the ``planner`` training regime;
``oracle``: the full-knowledge scripted planner (the movers' true future): the solvability ceiling and the teacher;
``baseline``: a trivial reference."""


@dataclass(frozen=True)
class AgentInfo:
    """One named agent.

    Attributes:
        name: The name on the command line and in reports.
        kind: One of ``KINDS``.
        summary: What it is, in a few words.
        trainer: For learned agents, what trains it: ``ddpg`` (``training.ddpg``) or ``sb3``
            (stable-baselines3 through ``training.baselines``); empty otherwise.
        algo: For learned agents, the training algorithm (``TrainConfig.algo``, ``deck-sim train --algo``):
            ``mddpg``, ``ddpg``, ``dqn`` or ``a2c``; empty: the agent's own name.
        recipe: For learned agents, which recipe of a scene trains them: empty for ``training/recipes/<scene>.toml``,
            else the suffix of ``<scene>-<recipe>.toml``.
        play: For learned agents, how each run behind the shipped file acts (``training.final_fit.PLAYS``): empty
            for the actor the run ships; ``averaged-select``: its averaged actor choosing each action by the run's
            own critic. Such an agent is another way of acting of the runs of the agent with the same recipe and
            algorithm, not other runs.
    """

    name: str
    kind: str
    summary: str
    trainer: str = ""
    algo: str = ""
    recipe: str = ""
    play: str = ""


AGENTS: dict[str, AgentInfo] = {
    a.name: a
    for a in (
        AgentInfo("mddpg", "learned", "the paper's MDDPG: DDPG on the observation and the MPC forecast", "ddpg"),
        AgentInfo("ddpg", "learned", "the same DDPG without prediction", "ddpg"),
        AgentInfo("dqn", "learned", "DQN over 17 discrete displacements (stable-baselines3), a short run at the "
                  "default fields", "sb3"),
        AgentInfo("a2c", "learned", "A2C (stable-baselines3), a short run at the default fields", "sb3"),
        AgentInfo("mddpg-reward", "learned", "MDDPG learnt from the reward alone (the paper's protocol)", "ddpg",
                  algo="mddpg", recipe="reward"),
        AgentInfo("ddpg-reward", "learned", "DDPG learnt from the reward alone", "ddpg", algo="ddpg", recipe="reward"),
        AgentInfo("mddpg-reward-select", "learned", "the same MDDPG runs, each its averaged actor choosing each "
                  "action by its own critic", "ddpg", algo="mddpg", recipe="reward", play="averaged-select"),
        AgentInfo("ddpg-reward-select", "learned", "the same DDPG runs, each its averaged actor choosing each "
                  "action by its own critic", "ddpg", algo="ddpg", recipe="reward", play="averaged-select"),
        AgentInfo("dqn-reward", "learned", "DQN at DDPG's budget with its own tuned fields (the paper's baseline)",
                  "sb3", algo="dqn", recipe="reward"),
        AgentInfo("a2c-reward", "learned", "A2C at DDPG's budget with its own tuned fields (the paper's baseline)",
                  "sb3", algo="a2c", recipe="reward"),
        AgentInfo("mddpg-planner", "learned", "MDDPG taught by the scripted planner on its own observation", "ddpg",
                  algo="mddpg", recipe="planner"),
        AgentInfo("ddpg-planner", "learned", "DDPG taught by the scripted planner on its own observation", "ddpg",
                  algo="ddpg", recipe="planner"),
        AgentInfo("apf", "classical", "artificial potential field"),
        AgentInfo("astar", "classical", "A* over a visibility graph with the movers' predicted sweeps"),
        AgentInfo("mpc", "classical", "CasADi/IPOPT MPC along the static shortest path"),
        AgentInfo("scripted-observed", "observer",
                  "the scripted planner (nose and tail checked) on the observation alone: the observed footprints "
                  "and the MPC forecast"),
        AgentInfo("scripted", "oracle", "full-knowledge planner: shortest path, speed checked on the true future"),
        AgentInfo("scripted-body", "oracle", "the same, checking the aircraft's nose and tail on its real turn"),
        AgentInfo("random", "baseline", "uniform random actions"),
        AgentInfo("zero", "baseline", "always the zero action (stand still)"),
    )
}
"""Every named agent, in the order help texts list them."""


def names(kind: str | None = None, trainer: str | None = None) -> tuple[str, ...]:
    """Agent names, optionally of one ``kind`` and/or ``trainer``, in registry order."""
    if kind is not None and kind not in KINDS:
        raise ValueError(f"unknown agent kind {kind!r}; expected one of {', '.join(KINDS)}")
    return tuple(
        a.name
        for a in AGENTS.values()
        if (kind is None or a.kind == kind) and (trainer is None or a.trainer == trainer)
    )


LEARNED = names("learned")
"""Agents trained by ``deck-sim train`` and shipped per scene in ``deck_sim/trained`` (``<scene>_<name>.npz``)."""
ALGOS = tuple(a for a in LEARNED if not AGENTS[a].algo)
"""The training algorithms (``deck-sim train --algo``): the learned agents that are their own algorithm."""


def training_algo(agent: str) -> str:
    """The training algorithm of learned ``agent`` (one of ``ALGOS``)."""
    return AGENTS[agent].algo or agent


def recipe_name(agent: str, scene: str) -> str:
    """The recipe (``training/recipes/<name>.toml``) that trains learned ``agent`` on ``scene``."""
    suffix = AGENTS[agent].recipe
    return f"{scene}-{suffix}" if suffix else scene
CLASSICAL = names("classical")
"""Classical references; they plan around the forecast of ``deck_sim.policies.REFERENCE_PREDICTOR``."""
OBSERVERS = names("observer")
"""Planners that read the observation alone, by name."""
OBSERVED_FIELDS = {"episode__static_size": True, "episode__mover_size": True, "episode__obstacle_shape": True}
"""The scene fields (``deck_sim.load`` keywords) that put every obstacle's footprint into the observation, which
``scripted-observed`` and the ``planner`` regime's teacher plan from (``Navigate.observed_view``)."""
ORACLES = names("oracle")
"""The full-knowledge scripted planner, by name."""
BASELINES = names("baseline")


def policy_help() -> str:
    """One sentence for ``--help`` listing every agent by kind, and actor files."""
    return (
        f"a shipped learned policy ({', '.join(LEARNED)}), a classical reference ({', '.join(CLASSICAL)}), "
        f"the scripted planner on the observation alone ({', '.join(OBSERVERS)}), "
        f"the full-knowledge planner ({', '.join(ORACLES)}), {' or '.join(BASELINES)}, or an actor .npz file; "
        "on a multi-aircraft scene, prioritised or independent (full-knowledge planners of several aircraft), or a "
        "learned policy, an actor file, random or zero acting for every aircraft"
    )
