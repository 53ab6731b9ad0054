"""Task-suite evaluation: agents x scenes x held-out episodes -> metrics, tables with confidence intervals, plots
and episode logs.

``evaluate(EvalConfig(...))`` plays ``episodes`` episodes of every scene with every agent. Episode ``i`` of a scene
is reset with seed ``seed + i`` (``episode_seed``), the same layout and movers for every agent, and every seed lies
below ``training.config.TRAIN_SEED_BASE``, where all training and demonstration seeds start, so no evaluation
episode was ever trained on. An episode's result depends on its seed alone (not on what the worker ran before), so
the serial, process-pool and Ray backends give identical results; units of a few episodes are handed to workers
as they free up. Each unit that records writes its own MCAP log (``logs/``).

Agents: the learned policies shipped in ``deck_sim/trained`` (``mddpg``, ``ddpg``, ``dqn``, ``a2c``), an actor file
(``label=path.npz``), and the references that need no training: ``apf``, ``astar`` and ``mpc`` (classical
planners, ``deck_sim.control.planners``; they plan around the MPC predictor's forecast, the same one MDDPG sees),
``scripted`` (the full-knowledge planner with the movers' true future: the solvability ceiling), ``scripted-body``
(the same planner checking an aircraft's nose and tail on the way its tracker will really take it), ``random`` and
``zero``.

``write_report`` turns the results into ``summary.json``, ``episodes.csv``, ``summary.csv`` and ``results.md``
(the paper's Tables 1-3 beside ours), and ``plot_learning_curves`` / ``plot_trajectories`` draw the figures.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import platform
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from deck_sim.metrics import (
    OUTCOMES,
    mean_interval,
    near_misses,
    prediction_errors,
    rate_interval,
    shortest_path,
)
from training.config import TRAIN_SEED_BASE

log = logging.getLogger(__name__)

LEARNED_AGENTS = ("mddpg", "ddpg", "dqn", "a2c")
"""Agents trained by ``deck-sim train`` and shipped per scene in ``deck_sim/trained``."""
CLASSICAL_AGENTS = ("apf", "astar", "mpc")
"""Classical references of ``deck_sim.control.planners``; they plan around the forecast of
``deck_sim.policies.REFERENCE_PREDICTOR``."""
OTHER_AGENTS = ("scripted", "scripted-body", "random", "zero")
AGENTS = LEARNED_AGENTS + CLASSICAL_AGENTS + OTHER_AGENTS
DEFAULT_SEED = 100_000
"""Seed of episode 0 of an evaluation (episode i: DEFAULT_SEED + i)."""
BACKENDS = ("serial", "process", "ray")

PAPER = {
    # Success rate ("accuracy", mean of 100 sampled episodes) and mean path length / total turning angle
    # (degrees, Unity units) of paper Tables 1-3 (../shared/reference/paper.md); the paper reports deck scenes only.
    "success": {
        "deck1": {"dqn": 0.90, "a2c": 0.67, "ddpg": 0.92, "mddpg": 0.98},
        "deck2": {"dqn": 0.84, "a2c": 0.64, "ddpg": 0.82, "mddpg": 0.91},
    },
    "path_length": {
        "deck1": {"dqn": 438.22, "a2c": 352.60, "ddpg": 328.97, "mddpg": 328.95},
        "deck2": {"dqn": 465.45, "a2c": 324.16, "ddpg": 320.61, "mddpg": 315.68},
    },
    "turning_deg": {
        "deck1": {"dqn": 586.73, "a2c": 142.03, "ddpg": 139.96, "mddpg": 139.80},
        "deck2": {"dqn": 522.62, "a2c": 158.00, "ddpg": 134.28, "mddpg": 128.41},
    },
}


class EvalError(ValueError):
    """An evaluation was asked for something it cannot do: an unknown agent, backend or seed range."""


def episode_seed(seed: int, index: int) -> int:
    """The reset seed of evaluation episode ``index`` of an evaluation seeded ``seed``."""
    return seed + index


@dataclass(frozen=True)
class EvalConfig:
    """What to evaluate and how.

    Attributes:
        agents: Agent names (``AGENTS``) or ``label=path`` to an actor file.
        scenes: Scene names or TOML paths.
        episodes: Episodes per scene and agent.
        seed: Seed of episode 0; episode i is reset with ``seed + i``, all below ``TRAIN_SEED_BASE``.
        backend: ``serial``, ``process`` (a local process pool) or ``ray``.
        workers: Worker processes (process pool) or CPUs asked of a local Ray (default: the CPU count).
        ray_address: An existing Ray cluster's address; None starts a local one with ``workers`` CPUs.
        chunk: Episodes per work unit (what a worker runs and logs at a time).
        record: Episodes logged per scene and agent: ``all``, ``none`` or a count (the first ones).
        out: Folder for results and logs (None: return the results only).
        near_miss: Clearance in metres below which a pass counts as a near miss (None: half the scene's reach).
    """

    agents: tuple[str, ...]
    scenes: tuple[str, ...]
    episodes: int = 100
    seed: int = DEFAULT_SEED
    backend: str = "process"
    workers: int | None = None
    ray_address: str | None = None
    chunk: int = 5
    record: str = "2"
    out: str | None = None
    near_miss: float | None = None

    def validate(self) -> None:
        """Raise ``EvalError`` (or ``SceneSpecError``) naming the first bad field."""
        from deck_sim.scenes import load_scene

        if not self.agents:
            raise EvalError("no agents to evaluate")
        if not self.scenes:
            raise EvalError("no scenes to evaluate")
        for a in self.agents:
            agent_label(a)
        labels = [agent_label(a) for a in self.agents]
        if len(set(labels)) != len(labels):
            raise EvalError(f"agent names repeat: {labels}")
        names = [load_scene(s).name for s in self.scenes]
        if len(set(names)) != len(names):
            raise EvalError(f"scenes repeat (by their spec names): {names}")
        if self.episodes < 1:
            raise EvalError(f"episodes must be at least 1, got {self.episodes}")
        if self.seed < 0 or self.seed + self.episodes > TRAIN_SEED_BASE:
            raise EvalError(
                f"evaluation seeds {self.seed}..{self.seed + self.episodes - 1} must lie in [0, {TRAIN_SEED_BASE}), "
                "below every training seed"
            )
        if self.backend not in BACKENDS:
            raise EvalError(f"unknown backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        if self.workers is not None and self.workers < 1:
            raise EvalError(f"workers must be at least 1, got {self.workers}")
        if self.chunk < 1:
            raise EvalError(f"chunk must be at least 1, got {self.chunk}")
        record_count(self.record, self.episodes)
        if self.near_miss is not None and not self.near_miss > 0:
            raise EvalError(f"near_miss must be a positive distance in metres, got {self.near_miss}")


def agent_label(agent: str) -> str:
    """The name an agent is reported under (``label`` of ``label=path``); ``EvalError`` for an unknown name."""
    label, sep, path = agent.partition("=")
    if sep:
        if not label or not path:
            raise EvalError(f"agent {agent!r}: expected label=path/to/actor.npz")
        return label
    if agent not in AGENTS:
        raise EvalError(f"unknown agent {agent!r}; expected one of {', '.join(AGENTS)} or label=path/to/actor.npz")
    return agent


def record_count(record: str, episodes: int) -> int:
    """How many episodes per scene and agent ``record`` asks to log (``all``, ``none`` or a count)."""
    if record == "all":
        return episodes
    if record == "none":
        return 0
    try:
        n = int(record)
    except ValueError:
        raise EvalError(f"record must be 'all', 'none' or a number of episodes, got {record!r}") from None
    if n < 0:
        raise EvalError(f"record must not be negative, got {n}")
    return min(n, episodes)


def _scene_name(scene: str) -> str:
    """The name a scene's episodes are reported under: its spec's ``name`` (a TOML file's may differ from its stem)."""
    from deck_sim.scenes import load_scene

    return load_scene(scene).name


# -- one worker's side -----------------------------------------------------------------------------------------


def agent_overrides(agent: str, scene: str) -> dict[str, Any]:
    """The scene fields an agent runs with (``deck_sim.load`` keywords; ``deck_sim.policies.policy_overrides``)."""
    from deck_sim.policies import policy_overrides

    label, sep, path = agent.partition("=")
    return policy_overrides(path if sep else agent, _scene_name(scene))


def make_agent(agent: str, env: Any, seed: int = 0) -> Any:
    """The policy (``reset()``, ``act(observation)``) of ``agent`` acting in ``env``."""
    from deck_sim.policies import make_policy

    label, sep, path = agent.partition("=")
    return make_policy(path if sep else agent, env, seed=seed)


@dataclass(frozen=True)
class Unit:
    """A batch of episodes of one agent on one scene: what one worker runs (and logs) at a time."""

    agent: str
    scene: str
    indices: tuple[int, ...]
    seed: int
    log_path: str | None = None
    """MCAP log of the unit's episodes (None: not recorded)."""
    near_miss: float | None = None


_WORKER_CACHE: dict[tuple, Any] = {}


def _worker_env(scene: str, overrides: dict[str, Any]) -> Any:
    import deck_sim

    key = ("env", scene, tuple(sorted(overrides.items())))
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = deck_sim.load(scene, seed=0, **overrides)
    return _WORKER_CACHE[key]


def run_unit(unit: Unit) -> list[dict[str, Any]]:
    """Play the unit's episodes and measure each (one dict per episode, ``EpisodeRecord`` fields).

    The worker keeps its environments and policies between units (module cache); every episode is reset from
    its own seed, so the result does not depend on what ran before it.
    """
    from deck_sim.rollout import open_recorder, run_episode

    env = _worker_env(unit.scene, agent_overrides(unit.agent, unit.scene))
    key = ("policy", unit.agent, unit.scene)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = make_agent(unit.agent, env, seed=unit.seed)
    policy = _WORKER_CACHE[key]
    task = env.task
    recorder = None
    if unit.log_path is not None:
        Path(unit.log_path).parent.mkdir(parents=True, exist_ok=True)
        config = {"agent": unit.agent, "scene": unit.scene, "seed": unit.seed, "episodes": list(unit.indices)}
        recorder = open_recorder(unit.log_path, env, unit.seed, agent_label(unit.agent), config=config, overwrite=True)
    # the agent's centre never comes closer to an obstacle than its narrowest half-extent, so the shortest path of
    # a disc that wide is a lower bound of its path (it ends on the goal disc's edge: less the goal radius)
    _, half, rounding = task.agent.footprint
    body_width = float(np.min(half) + rounding)
    out = []
    try:
        for i in unit.indices:
            seed = episode_seed(unit.seed, i)
            if unit.agent == "random":  # its own stream, seeded per episode like the scene
                policy = make_agent(unit.agent, env, seed=seed)
            trace: dict[str, list] = {"start": [], "clear": [], "pred": [], "movers": []}

            def on_step(env: Any, ts: Any, action: Any, trace: dict[str, list] = trace) -> None:
                info = env.task.last_info
                if action is None:
                    trace["start"].append(np.array(info["position"], dtype=np.float64))
                trace["clear"].append(float(info["min_clearance"]))
                trace["pred"].append(np.array(info["prediction"], dtype=np.float64))
                trace["movers"].append(np.array(info["mover_positions"], dtype=np.float64))

            env.random_state.seed(seed)
            result = run_episode(env, policy, episode=i, on_step=on_step, recorder=recorder)
            view = task.planner_view()
            reference = max(
                shortest_path(view.statics, body_width, view.bounds, trace["start"][0], view.target_xy)
                - view.goal_radius,
                0.0,
            )
            threshold = unit.near_miss if unit.near_miss is not None else 0.5 * view.reach
            if task.predictor.name != "none" and trace["pred"][0].size:
                ade, fde, samples = prediction_errors(np.stack(trace["pred"]), np.stack(trace["movers"]))
            else:
                ade, fde, samples = float("nan"), float("nan"), 0
            row = {"agent": agent_label(unit.agent), "seed": seed, **result.as_dict()}
            row.update(
                predictor=task.predictor.name,
                shortest_path=reference,
                near_misses=near_misses(np.array(trace["clear"]), threshold),
                near_miss_m=threshold,
                ade=ade,
                fde=fde,
                prediction_samples=samples,
            )
            out.append(row)
    finally:
        if recorder is not None:
            recorder.close()
    return out


# -- backends --------------------------------------------------------------------------------------------------


def plan_units(cfg: EvalConfig) -> list[Unit]:
    """The work units of an evaluation, scene-major then agent then episode order."""
    n_record = record_count(cfg.record, cfg.episodes)
    units = []
    for scene in cfg.scenes:
        for agent in cfg.agents:
            label = agent_label(agent)
            for first in range(0, cfg.episodes, cfg.chunk):
                idx = tuple(range(first, min(first + cfg.chunk, cfg.episodes)))
                logged = tuple(i for i in idx if i < n_record)
                path = None
                if cfg.out is not None and logged:
                    path = str(Path(cfg.out).resolve() / "logs" / f"{_scene_name(scene)}-{label}-{first:04d}.mcap")
                units.append(Unit(agent, scene, logged, cfg.seed, path, cfg.near_miss))
                rest = tuple(i for i in idx if i >= n_record)
                if rest:
                    units.append(Unit(agent, scene, rest, cfg.seed, None, cfg.near_miss))
    return [u for u in units if u.indices]


def _serial(units: Sequence[Unit]) -> Iterator[list[dict]]:
    for u in units:
        yield run_unit(u)


def clear_worker_cache() -> None:
    """Drop the environments and policies this process keeps between units (benchmarks time cold starts)."""
    _WORKER_CACHE.clear()


def _warm(units: Sequence[Unit]) -> None:
    """Build, in this process, every environment and policy the units need, so forked workers inherit them
    instead of each building its own (an environment takes 1-3 s to build)."""
    for u in units:
        env = _worker_env(u.scene, agent_overrides(u.agent, u.scene))
        key = ("policy", u.agent, u.scene)
        if key not in _WORKER_CACHE:
            _WORKER_CACHE[key] = make_agent(u.agent, env, seed=u.seed)


def _process(units: Sequence[Unit], workers: int) -> Iterator[list[dict]]:
    method = "fork" if platform.system() == "Linux" else "spawn"
    if method == "fork":
        _warm(units)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context(method))
    try:
        pending = {pool.submit(run_unit, u) for u in units}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield f.result()
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)  # a failed unit stops the run: drop what has not started
        raise
    pool.shutdown(wait=True)


def _ray(units: Sequence[Unit], workers: int, address: str | None) -> Iterator[list[dict]]:
    try:
        import ray
    except ImportError as err:
        raise EvalError("backend 'ray' needs Ray: pip install 'deck-sim[ray]' (or pip install ray)") from err
    started = False
    if not ray.is_initialized():
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(run_unit)
        pending = [remote.remote(u) for u in units]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield ray.get(ref)
    finally:
        if started:
            ray.shutdown()


@dataclass
class EvalResults:
    """Every episode's record and the per scene-and-agent summaries of one evaluation."""

    config: EvalConfig
    episodes: list[dict[str, Any]]
    """One record per episode, sorted by scene, agent and episode index."""
    summaries: list[dict[str, Any]] = field(default_factory=list)
    wall_s: float = 0.0
    logs: list[str] = field(default_factory=list)
    """The MCAP logs this evaluation wrote (one per recorded work unit)."""

    def summary(self, scene: str, agent: str) -> dict[str, Any]:
        """The summary of ``agent`` on ``scene``; KeyError if it was not evaluated."""
        for s in self.summaries:
            if s["scene"] == scene and s["agent"] == agent:
                return s
        raise KeyError(f"no results for agent {agent!r} on scene {scene!r}")

    @staticmethod
    def merge(parts: Sequence[EvalResults]) -> EvalResults:
        """One result of several evaluations with the same episodes and seed (e.g. different agents per scene)."""
        if not parts:
            raise EvalError("nothing to merge")
        first = parts[0].config
        for p in parts[1:]:
            if (p.config.episodes, p.config.seed) != (first.episodes, first.seed):
                raise EvalError("only evaluations of the same episodes and seed can be merged")
        agents = tuple(dict.fromkeys(a for p in parts for a in p.config.agents))
        scenes = tuple(dict.fromkeys(s for p in parts for s in p.config.scenes))
        cfg = EvalConfig(**{**asdict(first), "agents": agents, "scenes": scenes})
        return EvalResults(
            cfg,
            [r for p in parts for r in p.episodes],
            [s for p in parts for s in p.summaries],
            sum(p.wall_s for p in parts),
            [path for p in parts for path in p.logs],
        )


def evaluate(cfg: EvalConfig, progress: Callable[[int, int, list[dict]], None] | None = None) -> EvalResults:
    """Run the evaluation ``cfg`` asks for and summarise it (writes nothing but the logs; see ``write_report``).

    Args:
        progress: Called after every finished unit with (episodes done, episodes in all, the unit's records).
    """
    cfg.validate()
    for scene in cfg.scenes:  # fail before any worker starts: every agent file exists and loads
        for agent in cfg.agents:
            agent_overrides(agent, scene)
    units = plan_units(cfg)
    workers = cfg.workers or os.cpu_count() or 1
    total = sum(len(u.indices) for u in units)
    if cfg.backend == "serial" or (cfg.backend == "process" and workers == 1):
        stream: Iterable[list[dict]] = _serial(units)
    elif cfg.backend == "process":
        stream = _process(units, workers)
    else:
        stream = _ray(units, workers, cfg.ray_address)
    t0 = time.perf_counter()
    rows: list[dict] = []
    for batch in stream:
        rows.extend(batch)
        if progress is not None and batch:
            progress(len(rows), total, batch)
    wall = time.perf_counter() - t0
    order = {
        (_scene_name(s), agent_label(a)): k for k, (s, a) in enumerate((s, a) for s in cfg.scenes for a in cfg.agents)
    }
    rows.sort(key=lambda r: (order[(r["scene"], r["agent"])], r["episode"]))
    res = EvalResults(cfg, rows, wall_s=wall, logs=sorted({u.log_path for u in units if u.log_path}))
    res.summaries = [summarize_agent(rows, _scene_name(s), agent_label(a)) for s in cfg.scenes for a in cfg.agents]
    return res


def same_results(a: Sequence[dict[str, Any]], b: Sequence[dict[str, Any]]) -> bool:
    """Whether two lists of records (episodes or summaries) are equal, NaN equal to NaN."""
    return json.dumps(_jsonable(list(a)), sort_keys=True) == json.dumps(_jsonable(list(b)), sort_keys=True)


# -- summaries and reports -------------------------------------------------------------------------------------


def summarize_agent(rows: Sequence[dict[str, Any]], scene: str, agent: str) -> dict[str, Any]:
    """Rates (with Wilson 95 % intervals) and means (with normal 95 % intervals) of one agent on one scene.

    Path length, its ratio to the shortest static path, turning angle and time to goal are over successful
    episodes (as the paper's tables); reward, clearance and near misses over all; ADE/FDE over the episodes the
    predictor ran in, weighted by the (step, mover) samples scored.
    """
    mine = [r for r in rows if r["scene"] == scene and r["agent"] == agent]
    n = len(mine)
    out: dict[str, Any] = {"scene": scene, "agent": agent, "episodes": n}
    if not n:
        return out
    out["predictor"] = mine[0]["predictor"]
    for o in OUTCOMES:
        k = sum(r["outcome"] == o for r in mine)
        lo, hi = rate_interval(k, n)
        out[f"{o}_rate"], out[f"{o}_ci"] = k / n, [lo, hi]
    ok = [r for r in mine if r["outcome"] == "goal"]
    ratios = [r["path_length"] / r["shortest_path"] for r in ok if r["shortest_path"] > 0]
    for name, values in (
        ("reward", [r["reward"] for r in mine]),
        ("path_length", [r["path_length"] for r in ok]),
        ("shortest_ratio", ratios),
        ("turning_deg", [r["turning_angle_deg"] for r in ok]),
        ("time_to_goal", [r["sim_time"] for r in ok]),
        ("min_clearance", [r["min_clearance"] for r in mine]),
        ("near_misses", [r["near_misses"] for r in mine]),
    ):
        m, lo, hi = mean_interval(values)
        out[name], out[f"{name}_ci"] = m, [lo, hi]
    out["worst_clearance"] = float(min(r["min_clearance"] for r in mine))
    out["near_miss_m"] = float(mine[0]["near_miss_m"])
    scored = [r for r in mine if r["prediction_samples"] > 0]
    weights = np.array([r["prediction_samples"] for r in scored], dtype=np.float64)
    for name in ("ade", "fde"):
        out[name] = float(np.average([r[name] for r in scored], weights=weights)) if scored else float("nan")
    out["collision_partners"] = _count(r["collision_partner"] for r in mine if r["outcome"] == "collision")
    return out


def _count(items: Iterable[str | None]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for it in items:
        kind = str(it).rstrip("0123456789_/").split("/")[-1] or str(it)
        counts[kind] = counts.get(kind, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def _pct(s: dict, key: str) -> str:
    lo, hi = s[f"{key}_ci"]
    return f"{100 * s[f'{key}_rate']:.1f} ({100 * lo:.0f}-{100 * hi:.0f})"


def _num(s: dict, key: str, spec: str = ".1f") -> str:
    v = s.get(key, float("nan"))
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    lo, hi = s[f"{key}_ci"]
    half = (hi - lo) / 2
    return f"{v:{spec}} ± {half:{spec}}"


def _paper(table: str, scene: str, agent: str, spec: str) -> str:
    v = PAPER[table].get(scene, {}).get(agent)
    if v is None:
        return "-"
    return f"{100 * v:.0f}" if table == "success" else f"{v:{spec}}"


def _find(res: EvalResults, scene: str, agent: str) -> dict[str, Any] | None:
    try:
        return res.summary(scene, agent)
    except KeyError:
        return None


def _evaluated(res: EvalResults, scenes: list[str], agents: list[str]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    """(scene, agent, summary) of every pair that was evaluated, scene-major."""
    for s in scenes:
        for a in agents:
            x = _find(res, s, a)
            if x is not None:
                yield s, a, x


def markdown_tables(res: EvalResults) -> str:
    """The paper's tables (success; path length and turning angle) with ours beside them, then every metric.

    A scene and agent pair that was not evaluated reads ``n/a``.
    """
    scenes = list(dict.fromkeys(s["scene"] for s in res.summaries))
    agents = list(dict.fromkeys(s["agent"] for s in res.summaries))
    n = res.config.episodes
    lines = [
        f"Each cell: {n} held-out episodes per scene and agent (seeds {res.config.seed}-{res.config.seed + n - 1}); "
        "rates in % with Wilson 95 % intervals, means ± the half-width of their Student-t 95 % interval. "
        "Path length, its ratio and turning angle are over successful episodes, as in the paper. "
        "`apf`, `astar`, `mpc` and `scripted` plan on the task's privileged view (every obstacle's exact footprint "
        "and the movers' forecast), not on the observation the learned agents get.",
        "",
        "**Success rate, % (paper Table 1)**: the paper's figure is the mean of 100 success rates sampled from its "
        "training curves in Unity; ours is the shipped policy on held-out episodes.",
        "",
        "| agent | " + " | ".join(f"{s} ours | {s} paper" for s in scenes) + " |",
        "|---|" + "---:|---:|" * len(scenes),
    ]
    for a in agents:
        cells = []
        for s in scenes:
            x = _find(res, s, a)
            cells += [_pct(x, "goal") if x else "n/a", _paper("success", s, a, ".0f")]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "**Path length and turning angle (paper Tables 2-3)**: ours in metres and as a ratio to the shortest path "
        "around the static obstacles of a disc as wide as the agent's narrowest half-extent, ending on the goal "
        "disc (a lower bound of any collision-free path; the paper's Unity units do not convert); turning angle "
        "in degrees per episode.",
        "",
        "| agent | scene | length m | length / shortest | turning deg | paper length (Unity) | paper turning deg |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for s, a, x in _evaluated(res, scenes, agents):
        lines.append(
            f"| {a} | {s} | {_num(x, 'path_length')} | {_num(x, 'shortest_ratio', '.3f')} | "
            f"{_num(x, 'turning_deg')} | {_paper('path_length', s, a, '.2f')} | "
            f"{_paper('turning_deg', s, a, '.2f')} |"
        )
    lines += [
        "",
        "**Reward and safety** (the paper gives reward only as curves: about 150 at the plateau for DQN, DDPG and "
        "MDDPG, about 100 for A2C, on its own reward constants)",
        "",
        "Near misses: passes closer than the threshold (clearance between the agent's disc and an obstacle's "
        "footprint); worst clearance: the smallest over all episodes (negative: the discs overlapped).",
        "",
        "| agent | scene | predictor | collision % | timeout % | off surface % | diverged % | mean reward "
        "| time to goal s | near misses / ep (threshold) | worst clearance m | ADE m | FDE m |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s, a, x in _evaluated(res, scenes, agents):
        ade = "-" if math.isnan(x["ade"]) else f"{x['ade']:.2f}"
        fde = "-" if math.isnan(x["fde"]) else f"{x['fde']:.2f}"
        lines.append(
            f"| {a} | {s} | {x['predictor']} | {_pct(x, 'collision')} | {_pct(x, 'timeout')} | "
            f"{_pct(x, 'off_surface')} | {_pct(x, 'diverged')} | {_num(x, 'reward')} | "
            f"{_num(x, 'time_to_goal')} | {_num(x, 'near_misses', '.2f')} ({x['near_miss_m']:g} m) | "
            f"{x['worst_clearance']:.2f} | {ade} | {fde} |"
        )
    return "\n".join(lines) + "\n"


def _jsonable(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    return x


def machine() -> str:
    """A one-line description of this machine (for reports)."""
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def write_report(res: EvalResults, out: str | os.PathLike[str]) -> dict[str, Path]:
    """Write ``summary.json``, ``summary.csv``, ``episodes.csv`` and ``results.md`` to ``out``; returns the paths.

    Each file is written to a temporary name and renamed, so a failure leaves no half-written report.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / k for k in ("summary.json", "summary.csv", "episodes.csv", "results.md")}
    meta = {
        "config": asdict(res.config),
        "machine": machine(),
        "wall_s": res.wall_s,
        "evaluated": [[s["scene"], s["agent"]] for s in res.summaries],  # a merged config may list more pairs
        "summaries": res.summaries,
        "episodes": res.episodes,
    }
    _atomic_text(paths["summary.json"], json.dumps(_jsonable(meta), indent=1))
    _atomic_csv(paths["episodes.csv"], res.episodes)
    flat = []
    for s in res.summaries:
        row = {}
        for k, v in s.items():
            if isinstance(v, list):
                row[f"{k}_low"], row[f"{k}_high"] = v
            elif isinstance(v, dict):
                row[k] = json.dumps(v)
            else:
                row[k] = v
        flat.append(row)
    _atomic_csv(paths["summary.csv"], flat)
    _atomic_text(paths["results.md"], "# deck_sim evaluation\n\n" + markdown_tables(res))
    return paths


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _atomic_csv(path: Path, rows: Sequence[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fields: list[str] = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, path)


def plot_learning_curves(runs: dict[str, str | os.PathLike[str]], out: str | os.PathLike[str], title: str = "") -> Path:
    """Average reward and success against training steps (the paper's Figs. 8-11) from training run folders.

    Args:
        runs: label -> a run folder written by ``deck-sim train`` (its ``eval.csv``: held-out evaluations).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4))
    FigureCanvasAgg(fig)
    ax_r, ax_s = fig.subplots(1, 2)
    for label, run in runs.items():
        path = Path(run) / "eval.csv"
        if not path.exists():
            raise FileNotFoundError(f"{path}: no evaluation log in run folder {run} (train with deck-sim train)")
        with open(path) as f:
            rows = list(csv.DictReader(f))
        if not rows:
            raise ValueError(f"{path} holds no evaluation rows")
        polished = [r for r in rows if r.get("polished") == "1"]  # the final cloning fit, at the last step
        rows = [r for r in rows if r.get("polished") != "1"]
        step = [float(r["step"]) for r in rows]
        (line,) = ax_r.plot(step, [float(r["reward"]) for r in rows], marker="o", ms=3, label=label)
        ax_s.plot(step, [100 * float(r["success"]) for r in rows], marker="o", ms=3, label=label)
        for r in polished:
            kw = {"marker": "*", "ms": 10, "color": line.get_color(), "linestyle": "none"}
            ax_r.plot([float(r["step"])], [float(r["reward"])], **kw)
            ax_s.plot([float(r["step"])], [100 * float(r["success"])], **kw)
    ax_r.set(xlabel="environment steps", ylabel="average episode reward (held-out)", title=title or "reward")
    ax_s.set(xlabel="environment steps", ylabel="success % (held-out)", title="success", ylim=(0, 100))
    for ax in (ax_r, ax_s):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out


def plot_trajectories(res: EvalResults, out_dir: str | os.PathLike[str], per_agent: int = 1) -> list[Path]:
    """A top-down PNG of the first ``per_agent`` logged episodes of every scene and agent (from the MCAP logs)."""
    from deck_sim.recording import EpisodeLog
    from deck_sim.recording.plot import plot_episode

    out_dir = Path(out_dir)
    written = []
    for path in map(Path, res.logs):
        if not path.stem.endswith("-0000"):  # the first unit of each scene and agent holds its first episodes
            continue
        episodes = EpisodeLog(path).episodes
        for ep in episodes[:per_agent]:
            dest = out_dir / f"{path.stem.removesuffix('-0000')}-episode{ep.index}.png"
            written.append(plot_episode(ep, dest, width_inches=12.0))
    return written


__all__ = [
    "AGENTS",
    "EvalConfig",
    "EvalError",
    "EvalResults",
    "episode_seed",
    "evaluate",
    "markdown_tables",
    "plot_learning_curves",
    "plot_trajectories",
    "clear_worker_cache",
    "run_unit",
    "same_results",
    "summarize_agent",
    "write_report",
]
