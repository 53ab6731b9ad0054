"""Mover prediction on tracks recorded from the simulator: constant velocity, CTRV, MPC and oracle, in one run.

For each scene (deck1, deck2, square) and each setting of ``movers.yield_to_agent`` (on, as shipped, and off),
records the movers' tracks over a few episodes with held-out seeds (>= 5000). The agent is driven by the
full-knowledge ``ScriptedPolicy`` planning on the task's oracle prediction (so episodes look like real ones:
the agent taxis to its catapult and movers meet it), or stands still (``--agent still``). An episode ends at
``ts.last()`` (or is cut after ``--steps``) and the next starts with an explicit ``env.reset()``: tracks are never
joined across episodes.

Every predictor is then replayed over the SAME recorded tracks, step by step with the history the task itself
would hand it (padded with the first position at an episode's start):

    constant_velocity  least-squares line over the last 4 samples (the task's ``constant_velocity``)
    ctrv               constant speed and turn rate (``prediction_synthetic.ConstantTurnRate``)
    mpc                the task's ``mpc`` predictor (``MPCPredictor``, default settings)
    task_oracle        what the recording task's own ``oracle`` predicted (it simulates ahead with the agent
                       braking where it stands: exact unless a mover reacts to the moving agent)
    oracle             the recorded future itself (zero error by construction; a check of the scoring)

Printed per scene, yield setting and predictor: ADE and FDE (m) over the horizon N = 10 at the decision period
0.5 s, FDE as a ratio to constant velocity, FDE split by phase (cruising, turning, braking, dwelling, departing;
labelled from the movers' true modes, ``prediction_synthetic.phase_labels``) and the wall time of one ``predict``
call for all the scene's movers (square: 13), fastest/median of 5 replays; then how many samples have a wheeled
mover pushed backwards by another (a simulator artefact no predictor of intent expects) and the MPC ratio without
them. Then: MPC time for 13 wheeled movers (synthetic tracks), a deck2 control step (``env.step``, predictor
``none``) timed in the same run, prediction as a fraction of it, the issue's targets, and the machine.

    python benchmarks/prediction.py [--episodes 8] [--steps 240] [--seed 5000] [--agent scripted|still]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from typing import Any  # noqa: E402

import casadi  # noqa: E402
import numpy as np  # noqa: E402
from common import machine  # noqa: E402
from prediction_synthetic import (  # noqa: E402
    PHASES,
    ConstantTurnRate,
    SyntheticTracks,
    phase_labels,
    time_predictor,
)

import deck_sim  # noqa: E402
from deck_sim.behaviour import DWELLING  # noqa: E402
from deck_sim.control.mpc_predictor import MPCPredictor, MPCPredictorSettings  # noqa: E402
from deck_sim.control.prediction import ConstantVelocity, Predictor  # noqa: E402
from deck_sim.policies import ScriptedPolicy, ZeroPolicy  # noqa: E402
from deck_sim.types import ObstacleKind, ObstacleTracks  # noqa: E402

SCENES = ("deck1", "deck2", "square")
HORIZON = 10
"""Predicted steps N."""
DT = 0.5
"""The task's decision period, s."""
HISTORY = 10
"""Samples of history the task keeps (``episode.history``)."""


@dataclass
class EpisodeTrack:
    """One recorded episode of one scene, sampled at every control step (row 0 is the episode's start).

    Attributes:
        scene: Scene name.
        yield_to_agent: Whether the movers yielded to the agent.
        dt: Sampling period, s.
        positions: (n, T, 2) movers' positions, m.
        yaw: (n, T) movers' body yaw, rad (meaningless for pedestrians).
        dwelling: (n, T) bool, the mover's behaviour mode is dwelling at a spot.
        cruise: (n, T) cruise speed of the mover's current trip, m/s.
        cmd_speed: (n, T) speed commanded for the next step, m/s.
        kinds: (n,) ``ObstacleKind`` values.
        spots: (k, 2) the map's special spots, m.
        task_oracle: (n, T, N, 2) the recording task's own oracle prediction at every step, m.
        ended: Why the episode ended: "goal", "collision", "time limit", "cut" (``--steps``) or "other".
    """

    scene: str
    yield_to_agent: bool
    dt: float
    positions: np.ndarray
    yaw: np.ndarray
    dwelling: np.ndarray
    cruise: np.ndarray
    cmd_speed: np.ndarray
    kinds: np.ndarray
    spots: np.ndarray
    task_oracle: np.ndarray
    ended: str = "other"

    @property
    def steps(self) -> int:
        """Number of samples T."""
        return int(self.positions.shape[1])


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-pi, pi), rad."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def record(
    scene: str, seed: int, episodes: int, max_steps: int, yield_to_agent: bool, agent: str = "scripted"
) -> list[EpisodeTrack]:
    """Record ``episodes`` episodes of ``scene`` with the task's oracle predictor, each cut at ``max_steps``.

    Args:
        scene: Scene name.
        seed: Environment seed (held-out: >= 5000); episodes follow one another in one environment.
        episodes: Number of episodes.
        max_steps: Control steps after which an episode is cut (a fresh one is started with ``env.reset``).
        yield_to_agent: The scene's ``movers.yield_to_agent``.
        agent: "scripted" (``ScriptedPolicy``) or "still" (zero actions).
    """
    env = deck_sim.load(
        scene, seed=seed, episode__predictor="oracle", episode__horizon=HORIZON, movers__yield_to_agent=yield_to_agent
    )
    task = env.task
    policy = ScriptedPolicy(env) if agent == "scripted" else ZeroPolicy()
    out: list[EpisodeTrack] = []
    buf: dict[str, list[np.ndarray]] = {}

    def begin() -> None:
        buf.clear()
        for k in ("positions", "yaw", "dwelling", "cruise", "cmd_speed", "task_oracle"):
            buf[k] = []
        sample()

    def sample() -> None:
        info, beh = task.last_info, task._behaviour
        buf["positions"].append(info["mover_positions"].copy())
        buf["yaw"].append(info["mover_yaw"].copy())
        buf["dwelling"].append(beh.mode == DWELLING)
        buf["cruise"].append(beh.cruise.copy())
        buf["cmd_speed"].append(beh.cmd_speed.copy())
        buf["task_oracle"].append(info["prediction"].copy())

    def finish(ended: str) -> None:
        def stack(k: str) -> np.ndarray:
            return np.stack(buf[k], axis=1)

        out.append(
            EpisodeTrack(
                scene=scene,
                yield_to_agent=yield_to_agent,
                dt=task.spec.episode.control_period,
                positions=stack("positions"),
                yaw=stack("yaw"),
                dwelling=stack("dwelling"),
                cruise=stack("cruise"),
                cmd_speed=stack("cmd_speed"),
                kinds=task._kinds.copy(),
                spots=task._spot_xy.copy(),
                task_oracle=stack("task_oracle"),
                ended=ended,
            )
        )

    ts = env.reset()
    policy.reset()
    begin()
    while len(out) < episodes:
        ts = env.step(policy.act(ts.observation))
        if ts.first():  # composer reset inside step after the previous ``last``: cannot happen here
            raise RuntimeError("unexpected episode start; episodes must be split at ts.last()")
        sample()
        info = task.last_info
        if ts.last() or len(buf["positions"]) > max_steps:
            if info["reached_goal"]:
                ended = "goal"
            elif info["collision"] is not None:
                ended = "collision"
            elif ts.last():
                ended = "time limit"
            else:
                ended = "cut"
            finish(ended)
            if len(out) < episodes:
                ts = env.reset()  # explicit reset: composer's own would come inside the next ``step``
                policy.reset()
                begin()
    return out


def kinematics(ep: EpisodeTrack) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speeds m/s, headings rad, turn rates rad/s), each (n, T), from the recorded track.

    Speed over the period ending at each sample; heading: body yaw (wheeled) or direction of travel
    (pedestrians, held while slower than 0.05 m/s); turn rate: heading change over the period ending there.
    """
    p = ep.positions
    d = np.diff(p, axis=1, prepend=p[:, :1])
    speed = np.hypot(d[..., 0], d[..., 1]) / ep.dt
    heading = ep.yaw.copy()
    ped = ep.kinds == ObstacleKind.PEDESTRIAN
    if ped.any():
        travel = np.arctan2(d[..., 1], d[..., 0])
        for i in np.flatnonzero(ped):
            h = 0.0
            for t in range(ep.steps):
                if speed[i, t] > 0.05:
                    h = travel[i, t]
                heading[i, t] = h
    turn = np.diff(np.unwrap(heading, axis=1), axis=1, prepend=heading[:, :1]) / ep.dt
    return speed, heading, turn


def pushed_flags(ep: EpisodeTrack, threshold: float = 0.2) -> np.ndarray:
    """(n, T) bool: a wheeled mover moved backwards (against its body yaw) faster than ``threshold`` m/s over the
    period ending there. Movers never reverse on their own, so this is a mover being pushed (by another mover in
    a head-on stand-off, or by the agent)."""
    p = ep.positions
    d = np.diff(p, axis=1, prepend=p[:, :1])
    along = (d[..., 0] * np.cos(ep.yaw) + d[..., 1] * np.sin(ep.yaw)) / ep.dt
    return (along < -threshold) & (ep.kinds == ObstacleKind.WHEELED)[:, None]


def departing_flags(ep: EpisodeTrack, speed: np.ndarray) -> np.ndarray:
    """(n, T) bool: the mover left its spot (or started the episode) and still accelerates to its cruise speed.

    Set when a mover starts driving (every mover departs at an episode's start); cleared once it reaches 95% of
    its trip's cruise speed or is commanded slower than it goes (braking or yielding).
    """
    n, t_len = ep.dwelling.shape
    out = np.zeros((n, t_len), dtype=bool)
    dep = ~ep.dwelling[:, 0]
    for t in range(t_len):
        if t > 0:
            dep |= ep.dwelling[:, t - 1] & ~ep.dwelling[:, t]
        dep &= ~ep.dwelling[:, t]
        dep &= ~((speed[:, t] >= 0.95 * ep.cruise[:, t]) | (ep.cmd_speed[:, t] < speed[:, t] - 0.05))
        out[:, t] = dep
    return out


def labels(ep: EpisodeTrack, horizon: int) -> np.ndarray:
    """(n, T) index into ``PHASES`` of every step as a prediction start (-1 past the end), from the true modes."""
    speed, heading, turn = kinematics(ep)
    n = ep.positions.shape[0]
    tr = SyntheticTracks(
        dt=ep.dt,
        positions=ep.positions,
        true_positions=ep.positions,
        headings=heading,
        speeds=speed,
        turn_rates=turn,
        kinds=ep.kinds,
        spots=ep.spots,
        statics=np.zeros((0, 3)),
        target=np.zeros((n, ep.steps), dtype=int),
        dwelling=ep.dwelling,
        departing=departing_flags(ep, speed),
    )
    return phase_labels(tr, horizon)


@dataclass
class Scores:
    """Per-sample errors of one predictor over many episodes."""

    ade: list[np.ndarray] = field(default_factory=list)
    """Per call: (n,) mean displacement error over the horizon, m."""
    fde: list[np.ndarray] = field(default_factory=list)
    """Per call: (n,) displacement error at the horizon's end, m."""
    phase: list[np.ndarray] = field(default_factory=list)
    """Per call: (n,) phase index."""
    pushed: list[np.ndarray] = field(default_factory=list)
    """Per call: (n,) bool, the mover is being pushed backwards now (``pushed_flags``)."""
    seconds: list[float] = field(default_factory=list)
    """Wall time of every ``predict`` call (all movers), s."""
    fallbacks: int = 0
    """Movers that fell back to constant velocity."""
    solve_seconds: list[float] = field(default_factory=list)
    """MPC only: wall time of the compiled Function alone in every call (``last_solve_time_s``), s."""

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ade, fde, phase) concatenated over all samples."""
        return np.concatenate(self.ade), np.concatenate(self.fde), np.concatenate(self.phase)


def score(
    predictors: dict[str, Predictor], episodes: list[EpisodeTrack], horizon: int, history: int, skip: int = 0
) -> dict[str, Scores]:
    """Replay every predictor over every episode with the task's history; score every step with a full horizon.

    Every predictor is called at every step (the MPC predictor carries state from step to step), on the history
    the task would give it; steps before ``skip`` or whose horizon runs past the episode's end are not scored.
    Adds "task_oracle" (the recording task's own prediction) and "oracle" (the recorded future).
    """
    res = {k: Scores() for k in (*predictors, "task_oracle", "oracle")}
    for ep in episodes:
        lab = labels(ep, horizon)
        pushed = pushed_flags(ep)
        for p in predictors.values():
            p.reset(ep.spots, ep.kinds)
        padded = np.concatenate([np.repeat(ep.positions[:, :1], history - 1, axis=1), ep.positions], axis=1)
        for t in range(ep.steps):
            tracks = ObstacleTracks(dt=ep.dt, positions=padded[:, t : t + history], kinds=ep.kinds)
            scored = skip <= t < ep.steps - horizon
            truth = ep.positions[:, t + 1 : t + horizon + 1] if scored else None
            preds: dict[str, np.ndarray] = {}
            for name, p in predictors.items():
                t0 = time.perf_counter()
                out = p.predict(tracks)
                res[name].seconds.append(time.perf_counter() - t0)
                res[name].fallbacks += int(np.count_nonzero(out.fallback))
                if hasattr(p, "last_solve_time_s"):
                    res[name].solve_seconds.append(p.last_solve_time_s)
                preds[name] = out.positions
            if not scored:
                continue
            preds["task_oracle"] = ep.task_oracle[:, t]
            preds["oracle"] = truth
            for name, pred in preds.items():
                err = np.hypot(*(pred - truth).transpose(2, 0, 1))
                res[name].ade.append(err.mean(axis=1))
                res[name].fde.append(err[:, -1])
                res[name].phase.append(lab[:, t])
                res[name].pushed.append(pushed[:, t])
    return res


def time_replay(
    make: Callable[[], Predictor], episodes: list[EpisodeTrack], history: int, calls: int = 300, repeats: int = 5
) -> tuple[float, float]:
    """(fastest, median) over ``repeats`` replays of the mean wall time of one ``predict`` call, microseconds.

    Each replay runs a fresh predictor over the first ``calls`` steps of ``episodes`` (reset at every episode),
    as the task calls it. The fastest replay is the least disturbed by other load on a shared machine.
    """
    work = []
    for ep in episodes:
        padded = np.concatenate([np.repeat(ep.positions[:, :1], history - 1, axis=1), ep.positions], axis=1)
        steps = [
            ObstacleTracks(dt=ep.dt, positions=padded[:, t : t + history], kinds=ep.kinds) for t in range(ep.steps)
        ]
        work.append((ep, steps[: calls - sum(len(w[1]) for w in work)]))
        if sum(len(w[1]) for w in work) >= calls:
            break
    p = make()
    means = []
    for _ in range(repeats + 1):  # the first replay warms up
        total, count = 0.0, 0
        for ep, steps in work:
            p.reset(ep.spots, ep.kinds)
            for tracks in steps:
                t0 = time.perf_counter()
                p.predict(tracks)
                total += time.perf_counter() - t0
                count += 1
        means.append(1e6 * total / count)
    return float(np.min(means[1:])), float(np.median(means[1:]))


def time_control_step(scene: str, seed: int, steps: int, batches: int = 5) -> tuple[float, float]:
    """(fastest, median) over ``batches`` batches of the mean seconds of one ``env.step`` of ``scene``.

    Predictor "none", agent driven by ``ScriptedPolicy`` (its planning is not timed); steps in which composer
    resets the episode are left out.
    """
    env = deck_sim.load(scene, seed=seed, episode__predictor="none")
    policy = ScriptedPolicy(env)
    ts = env.reset()
    policy.reset()
    times = []
    for i in range(steps + 20):
        action = policy.act(ts.observation)
        t0 = time.perf_counter()
        ts = env.step(action)
        dt = time.perf_counter() - t0
        if ts.first():
            policy.reset()
        elif i >= 20:
            times.append(dt)
    means = [float(np.mean(b)) for b in np.array_split(np.array(times), batches)]
    return float(np.min(means)), float(np.median(means))


def print_table(title: str, res: dict[str, Scores], timing: dict[str, tuple[float, float]]) -> None:
    """Print one scene's table: ADE, FDE, FDE/cv, per-phase FDE/cv and FDE, us per predict call (fastest/median)."""
    _, base_fde, phase = res["constant_velocity"].arrays()
    counts = [int(np.count_nonzero(phase == i)) for i in range(len(PHASES))]
    print(title)
    print(
        f"  {len(phase)} scored samples (mover x step); by phase: "
        + ", ".join(f"{ph} {c / max(len(phase), 1):.0%}" for ph, c in zip(PHASES, counts, strict=True))
    )
    head = f"  {'predictor':<18}{'ADE m':>7}{'FDE m':>7}{'FDE/cv':>7}" + "".join(f"{ph:>12}" for ph in PHASES)
    print(head + f"{'us/step':>12}")
    for name, r in res.items():
        ade, fde, _ = r.arrays()
        row = f"  {name:<18}{ade.mean():7.2f}{fde.mean():7.2f}{fde.mean() / base_fde.mean():7.2f}"
        for i in range(len(PHASES)):
            m = phase == i
            if m.any():
                ratio = fde[m].mean() / max(base_fde[m].mean(), 1e-9)
                row += f"{ratio:7.2f}{fde[m].mean():5.1f}"
            else:
                row += f"{'-':>12}"
        row += f"{timing[name][0]:7.0f}/{timing[name][1]:.0f}" if name in timing else f"{'-':>8}"
        print(row)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: record, score, time, print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=8, help="episodes per scene and yield setting")
    ap.add_argument("--steps", type=int, default=240, help="control steps at most per episode (0.5 s each)")
    ap.add_argument("--seed", type=int, default=5000, help="environment seed of every scene (held out: >= 5000)")
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated scene names")
    ap.add_argument("--agent", choices=("scripted", "still"), default="scripted")
    ap.add_argument("--skip", type=int, default=0, help="steps at each episode's start left unscored")
    ap.add_argument("--timing-steps", type=int, default=300, help="deck2 control steps timed")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*DISPLAY.*")
    t_start = time.perf_counter()

    settings = MPCPredictorSettings(horizon=HORIZON, dt=DT, history=HISTORY)
    t0 = time.perf_counter()
    mpc = MPCPredictor(settings)
    makers: dict[str, Callable[[], Any]] = {
        "constant_velocity": lambda: ConstantVelocity(horizon=HORIZON),
        "ctrv": lambda: ConstantTurnRate(horizon=HORIZON),
        "mpc": lambda: MPCPredictor(settings),
    }
    print(f"machine: {machine(casadi=casadi.__version__)}")
    print(
        f"MPC predictor: backend {mpc.backend}, built/loaded in {time.perf_counter() - t0:.2f} s; "
        f"horizon N = {HORIZON} at dt = {DT} s ({HORIZON * DT:.0f} s), history {HISTORY}; agent {args.agent}, "
        f"seed {args.seed}, {args.episodes} episodes x <= {args.steps} steps per scene and yield setting"
    )
    print(
        "columns: ADE/FDE over all scored samples; per phase FDE/cv ratio then FDE m; us/step: one predict call "
        "for all the scene's movers, fastest/median of 5 replays of 300 recorded steps"
    )
    mpc_us: dict[str, tuple[float, float]] = {}
    summary: list[str] = []
    for scene in args.scenes.split(","):
        for yield_to_agent in (True, False):
            t0 = time.perf_counter()
            eps = record(scene, args.seed, args.episodes, args.steps, yield_to_agent, args.agent)
            rec_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            res = score({k: m() if k != "mpc" else mpc for k, m in makers.items()}, eps, HORIZON, HISTORY, args.skip)
            timing = {k: time_replay(m, eps, HISTORY) for k, m in makers.items()}
            n_movers = eps[0].positions.shape[0]
            ends = ", ".join(f"{e.steps - 1} ({e.ended})" for e in eps)
            print_table(
                f"\n{scene}: {n_movers} movers, yield_to_agent={yield_to_agent}; episodes (steps, end): {ends}; "
                f"recorded in {rec_s:.0f} s, scored and timed in {time.perf_counter() - t0:.0f} s; "
                f"MPC fallbacks {res['mpc'].fallbacks}",
                res,
                timing,
            )
            ratio = res["mpc"].arrays()[1].mean() / res["constant_velocity"].arrays()[1].mean()
            pushed = np.concatenate(res["mpc"].pushed)
            if pushed.any():
                kept = ~pushed
                ratio_kept = res["mpc"].arrays()[1][kept].mean() / res["constant_velocity"].arrays()[1][kept].mean()
                print(
                    f"  {pushed.sum()} samples ({pushed.mean():.1%}) have a wheeled mover pushed backwards (sim "
                    f"artefact); without them MPC FDE is {ratio_kept:.2f}x constant velocity"
                )
            mpc_us[f"{scene}/{yield_to_agent}"] = timing["mpc"]
            fn_us = 1e6 * float(np.median(res["mpc"].solve_seconds))
            summary.append(
                f"{scene:<7} yield_to_agent={yield_to_agent!s:<5}: MPC FDE {ratio:.2f}x constant velocity; "
                f"{timing['mpc'][0]:.0f} us per step for {n_movers} movers (median call in the scoring pass "
                f"{1e6 * np.median(res['mpc'].seconds):.0f} us, of which compiled Function {fn_us:.0f} us)"
            )

    rng = np.random.default_rng(args.seed)
    fast13, med13 = time_predictor(lambda: MPCPredictor(settings), 13, HISTORY, DT, 200, rng)
    step_fast, step_med = time_control_step("deck2", args.seed, args.timing_steps)
    print(
        f"\nMPC, 13 wheeled movers (synthetic tracks, 7 batches of 200 calls): {fast13:.0f} us fastest batch, "
        f"{med13:.0f} us median"
    )
    print(
        f"deck2 control step (env.step, predictor none, scripted agent, {args.timing_steps} steps in 5 batches): "
        f"{1e3 * step_fast:.2f} ms fastest batch, {1e3 * step_med:.2f} ms median"
    )
    print("\ntargets:")
    for line in summary:
        print(f"  {line}")
    print("  MPC FDE <= 0.75x constant velocity on the deck scenes: see the deck1/deck2 lines above")
    line = f"  <= 300 us per control step for 13 movers: {fast13:.0f} us (wheeled, synthetic; median {med13:.0f})"
    if "square/True" in mpc_us:
        sq = mpc_us["square/True"]
        line += f", {sq[0]:.0f} us (square, 13 pedestrians; median {sq[1]:.0f})"
    print(line)
    if "deck2/True" in mpc_us:
        d2 = mpc_us["deck2/True"]
        print(
            f"  prediction <= 25% of a deck2 control step: deck2 MPC (9 movers) {d2[0]:.0f} us = "
            f"{d2[0] / (1e6 * step_fast):.1%} of the fastest batch's {1e3 * step_fast:.2f} ms "
            f"(medians: {d2[1] / (1e6 * step_med):.1%}); 13 movers {fast13 / (1e6 * step_fast):.1%} "
            f"(medians {med13 / (1e6 * step_med):.1%})"
        )
    print(f"total run time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
