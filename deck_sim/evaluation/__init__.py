"""Task-suite evaluation: agents x scenes x held-out episodes -> metrics, tables with confidence intervals, plots
and episode logs.

``evaluate(EvalConfig(...))`` plays ``episodes`` episodes of every scene with every agent. Episode ``i`` of a scene
is reset with seed ``seed + i`` (``episode_seed``), the same layout and movers for every agent, and every seed lies
below ``TRAIN_SEED_BASE``, where all training and demonstration seeds start, so no evaluation
episode was ever trained on. An episode's result depends on its seed alone (not on what the worker ran before), so
the serial, process-pool and Ray backends give identical results; units of a few episodes are handed to workers
as they free up. Each unit that records writes its own MCAP log (``logs/``).

Agents: the learned policies shipped in ``deck_sim/trained`` (``mddpg``, ``ddpg``, ``dqn``, ``a2c``), an actor file
(``label=path.npz``), and the references that need no training: ``apf``, ``astar`` and ``mpc`` (classical
planners, ``deck_sim.control.planners``; they plan around the MPC predictor's forecast, the same one MDDPG sees),
``scripted`` (the full-knowledge planner with the movers' true future: the solvability ceiling), ``scripted-body``
(the same planner checking an aircraft's nose and tail on the way its tracker will really take it),
``scripted-observed`` (that planner on the observation alone: the observed footprints and the MPC forecast; the
teacher of the ``planner`` training regime), ``random`` and ``zero``.

``write_report`` turns the results into ``summary.json``, ``episodes.csv``, ``summary.csv`` and ``results.md``
(the paper's Tables 1-3 beside ours), and ``plot_learning_curves`` / ``plot_trajectories`` draw the figures.
"""


from deck_sim.evaluation.harness import (
    AGENTS,
    BACKENDS,
    DEFAULT_AGENTS,
    DEFAULT_SEED,
    TRAIN_SEED_BASE,
    EvalConfig,
    EvalError,
    EvalResults,
    Unit,
    agent_label,
    clear_worker_cache,
    episode_seed,
    evaluate,
    plan_units,
    record_count,
    run_unit,
    same_results,
)
from deck_sim.evaluation.plots import plot_learning_curves, plot_trajectories
from deck_sim.evaluation.report import PAPER, machine, markdown_tables, summarize_agent, write_report

__all__ = [
    "AGENTS",
    "BACKENDS",
    "DEFAULT_AGENTS",
    "DEFAULT_SEED",
    "PAPER",
    "TRAIN_SEED_BASE",
    "EvalConfig",
    "EvalError",
    "EvalResults",
    "Unit",
    "agent_label",
    "clear_worker_cache",
    "episode_seed",
    "evaluate",
    "machine",
    "markdown_tables",
    "plan_units",
    "plot_learning_curves",
    "plot_trajectories",
    "record_count",
    "run_unit",
    "same_results",
    "summarize_agent",
    "write_report",
]
