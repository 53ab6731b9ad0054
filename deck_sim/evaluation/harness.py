"""The evaluation's engine: what to evaluate (``EvalConfig``), work units of a few episodes, the serial,
process-pool and Ray backends that run them, and ``evaluate``, which gathers every episode's record."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import platform
import signal
import socket
import time
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from deck_sim import agents
from deck_sim.evaluation.report import jsonable, summarize_agent
from deck_sim.metrics import near_misses, prediction_errors, shortest_path

log = logging.getLogger(__name__)

AGENTS = tuple(agents.AGENTS)
"""Every agent name an evaluation accepts (``deck_sim.agents``), besides ``label=path`` to an actor file."""
TEAM_AGENTS = ("prioritised", "independent")
"""The full-knowledge planners of several aircraft (``deck_sim.policies.TEAM_PLANNERS``), for multi-aircraft scenes."""
DEFAULT_AGENTS = ("mddpg", "ddpg", "apf", "astar", "mpc")
"""What ``deck-sim eval`` evaluates unless told: the paper's learned agents and the classical references."""
TRAIN_SEED_BASE = 1_000_000
"""Every training and demonstration episode is seeded at or above this; evaluation seeds lie below it."""
DEFAULT_SEED = 100_000
"""Seed of episode 0 of an evaluation (episode i: DEFAULT_SEED + i)."""
BACKENDS = ("serial", "process", "ray")


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
        specs = [load_scene(s) for s in self.scenes]
        for spec in specs:
            if spec.multi_agent:
                bad = [a for a in self.agents if not _team_capable(a)]
                why = (f"scene {spec.name!r} has {spec.agents.count} aircraft; agents {bad} plan for one (for several: "
                       f"{', '.join(TEAM_AGENTS)}, a learned policy or an actor file shared by every aircraft)")
            else:
                bad = [a for a in self.agents if a in TEAM_AGENTS]
                why = f"agents {bad} plan for several aircraft; scene {spec.name!r} has one"
            if bad:
                raise EvalError(why)
        names = [s.name for s in specs]
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
    if agent not in AGENTS and agent not in TEAM_AGENTS:
        raise EvalError(f"unknown agent {agent!r}; expected one of {', '.join(AGENTS)}, for several aircraft "
                        f"{', '.join(TEAM_AGENTS)}, or label=path/to/actor.npz")
    return agent


def _team_capable(agent: str) -> bool:
    """Whether ``agent`` can act for every aircraft of a multi-aircraft scene (``make_team_policy``)."""
    label, sep, path = agent.partition("=")
    return bool(sep) or agent in TEAM_AGENTS or agent in agents.LEARNED or agent in ("random", "zero")


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
    """The scene fields an agent runs with (``deck_sim.load`` keywords; ``deck_sim.policies.policy_overrides``, or
    ``team_policy_overrides`` on a multi-aircraft scene)."""
    from deck_sim.policies import policy_overrides, team_policy_overrides
    from deck_sim.scenes import load_scene

    label, sep, path = agent.partition("=")
    overrides = team_policy_overrides if load_scene(scene).multi_agent else policy_overrides
    return overrides(path if sep else agent, _scene_name(scene))


def make_agent(agent: str, env: Any, seed: int = 0) -> Any:
    """The policy (``reset()``, ``act(observation)``) of ``agent`` acting in ``env``: a team policy
    (``make_team_policy``) acting for every aircraft of a multi-aircraft scene."""
    from deck_sim.policies import make_policy, make_team_policy

    label, sep, path = agent.partition("=")
    make = make_team_policy if env.task.spec.multi_agent else make_policy
    return make(path if sep else agent, env, seed=seed)


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
    if task.spec.multi_agent:
        try:
            return _team_unit(unit, env, policy, recorder)
        finally:
            if recorder is not None:
                recorder.close()
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


def _team_unit(unit: Unit, env: Any, policy: Any, recorder: Any) -> list[dict[str, Any]]:
    """``run_unit`` on a multi-aircraft scene: one record per aircraft of every episode, with its episode's team
    figures (every aircraft arrived, makespan, aircraft-aircraft collisions) and its shortest way
    (``run_team_episode``); no prediction errors (every aircraft's forecast is of the others' choices)."""
    from deck_sim.rollout import run_team_episode

    task = env.task
    out = []
    for i in unit.indices:
        seed = episode_seed(unit.seed, i)
        if unit.agent == "random":  # its own stream, seeded per episode like the scene
            policy = make_agent(unit.agent, env, seed=seed)
        clear: list[list[float]] = [[] for _ in range(task.n_agents)]
        live = [True] * task.n_agents

        def on_step(env: Any, ts: Any, action: Any, clear: list[list[float]] = clear, live: list[bool] = live) -> None:
            for k, a in enumerate(env.task.last_info["agents"]):
                if live[k]:  # (the clearances an aircraft had while it taxied, its done step included)
                    clear[k].append(float(a["min_clearance"]))
                    live[k] = not a["done"]

        env.random_state.seed(seed)
        team = run_team_episode(env, policy, episode=i, on_step=on_step, recorder=recorder)
        threshold = unit.near_miss if unit.near_miss is not None else 0.5 * task.spec.agent.reach
        for k, (name, result) in enumerate(zip(task.agent_names, team.aircraft, strict=True)):
            row = {"agent": agent_label(unit.agent), "seed": seed, "aircraft": name, **result.as_dict()}
            row.update(
                predictor=task.predictor.name,
                shortest_path=team.shortest[k],
                near_misses=near_misses(np.array(clear[k]), threshold),
                near_miss_m=threshold,
                ade=float("nan"),
                fde=float("nan"),
                prediction_samples=0,
                all_reached=team.all_reached,
                makespan=team.makespan,
                aircraft_collisions=team.aircraft_collisions,
            )
            out.append(row)
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


CAN_MASK = hasattr(signal, "pthread_sigmask")
"""Whether this platform blocks signals per thread (POSIX); elsewhere the workers only ignore Ctrl-C once started."""


def _worker_ignores_ctrl_c() -> None:
    """Pool initializer: Ctrl-C is the parent's to handle (it lets the running units finish, see ``_process``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if CAN_MASK:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _process(units: Sequence[Unit], workers: int) -> Iterator[list[dict]]:
    """Run ``units`` in ``workers`` processes. The workers ignore Ctrl-C (they start with it blocked, so that even
    one that arrives while they fork waits until they ignore it); in this process it cancels the units not started,
    waits for the running ones to finish writing their logs, and goes on as ``KeyboardInterrupt``."""
    method = "fork" if platform.system() == "Linux" else "spawn"
    if method == "fork":
        _warm(units)
    before = signal.pthread_sigmask(signal.SIG_BLOCK, ()) if CAN_MASK else None  # (reads the mask, changes nothing)
    pool: ProcessPoolExecutor | None = None
    try:
        try:
            if before is not None:
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context(method),
                                       initializer=_worker_ignores_ctrl_c)
            pending = {pool.submit(run_unit, u) for u in units}
        finally:
            if before is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)  # (a Ctrl-C that came meanwhile is raised here)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield f.result()
    except BaseException:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)  # a failed unit or Ctrl-C: drop the units not started
        raise
    pool.shutdown(wait=True)


def _ray(units: Sequence[Unit], workers: int, address: str | None) -> Iterator[list[dict]]:
    try:
        import ray
    except ImportError as err:
        raise EvalError("backend 'ray' needs Ray: pip install 'deck-sim[ray]' (or pip install ray)") from err
    started = init_ray(workers, address)
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


RAY_CONNECT_TIMEOUT_S = 10.0
"""How long ``check_ray_address`` waits for a Ray head to accept a connection."""


def init_ray(workers: int, address: str | None) -> bool:
    """Connect this process to Ray unless it is already: to the cluster at ``address`` or to a local Ray started
    with ``workers`` CPUs. An ``address`` is checked first (``check_ray_address``) even when this process is already
    connected, which then keeps its connection. Returns whether this call started or joined it (the caller then
    shuts it down when done)."""
    import ray

    if address:
        check_ray_address(address)  # (an unreachable address fails clearly whatever the process holds)
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    return True


def check_ray_address(address: str, timeout: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """Raise ``EvalError`` within ``timeout`` seconds if nothing accepts a TCP connection at a Ray ``address``
    (``host:port`` or ``ray://host:port``); ``ray.init`` itself would wait for minutes. ``auto`` and ``local`` are
    left to Ray."""
    if address in ("auto", "local"):
        return
    hostport = address.removeprefix("ray://").rstrip("/")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise EvalError(f"--ray-address {address!r}: expected host:port or ray://host:port")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as err:
        raise EvalError(
            f"--ray-address {address!r}: no Ray cluster answers there ({err}); start one with `ray start --head` "
            "or leave the option out to start a local Ray"
        ) from None


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
    done = 0
    # (closed on the way out, so that an error or Ctrl-C here also stops the workers' queued units)
    with contextlib.closing(stream) if isinstance(stream, Generator) else contextlib.nullcontext():
        for batch in stream:
            rows.extend(batch)
            done += len({(r["scene"], r["agent"], r["episode"]) for r in batch})  # (several rows per team episode)
            if progress is not None and batch:
                progress(done, total, batch)
    wall = time.perf_counter() - t0
    order = {
        (_scene_name(s), agent_label(a)): k for k, (s, a) in enumerate((s, a) for s in cfg.scenes for a in cfg.agents)
    }
    rows.sort(key=lambda r: (order[(r["scene"], r["agent"])], r["episode"], r.get("aircraft", "")))
    res = EvalResults(cfg, rows, wall_s=wall, logs=sorted({u.log_path for u in units if u.log_path}))
    res.summaries = [summarize_agent(rows, _scene_name(s), agent_label(a)) for s in cfg.scenes for a in cfg.agents]
    return res


def same_results(a: Sequence[dict[str, Any]], b: Sequence[dict[str, Any]]) -> bool:
    """Whether two lists of records (episodes or summaries) are equal, NaN equal to NaN."""
    return json.dumps(jsonable(list(a)), sort_keys=True) == json.dumps(jsonable(list(b)), sort_keys=True)


