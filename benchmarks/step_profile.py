"""Where the time of one control step goes, per scene: composer, the task's Python and raw MuJoCo.

Every hook of one ``env.step`` is wrapped with ``time.perf_counter`` (nested timers: each phase's own time, its
callees' subtracted) and the steps of a seeded, forward-biased random policy (as ``step_speed.py``) are timed;
resets are not counted. Prints, per scene, the microseconds per control step of every phase and its share of the
step, the step's total (instrumented and, from a second environment in the same run, uninstrumented), the time
above raw ``mj_step`` and the Python's part of it (all but the CasADi Function), per step, with the machine and the
load average. Single-threaded (OMP/MKL threads pinned to 1).

    python benchmarks/step_profile.py [--scenes deck1,deck2,square] [--steps 600] [--predictor mpc]

Phases (own time, callees excluded):
    composer        ``Environment.step`` itself: hooks dispatch, reward/discount/termination calls, time limit
    observation     composer's observation updater (``get_observation``: one array copy per key)
    action check    ``tasks.actions.checked_action``
    tracker         the agent's tracking controller (``control.tracking``)
    task hooks      the rest of ``Navigate.before_step`` / ``after_step`` (state shifts, bookkeeping)
    movers          ``MoverDriver.command`` around the behaviour: the actuator commands
    behaviour       ``MoverBehaviour.command_lists`` (``behaviour.py``), yield tests included
    routes          ``MoverBehaviour._depart``: a mover's next spot and its route (``geometry.VisibilityGraph``)
    mj_step         every raw ``mujoco.mj_step`` call: the fused substeps and composer's last one
    substeps        ``FusedStepper.substeps`` around its ``mj_step`` calls (sensor flags, warning counts)
    contacts        ``FusedStepper.check_contacts``
    divergence      ``FusedStepper.diverged``
    read state      ``FusedStepper.read_state``
    surface         ``FusedStepper.surface``
    prediction      ``Navigate._predict`` and the predictor's Python (input checks, copies, fallback test)
    casadi          the compiled CasADi Function's evaluation (``MPCPredictor``'s batch run)
    clearances      ``Clearances.__call__``
    reward          ``tasks.rewards`` (attraction, repulsion, total)
    obs build       ``Navigate._update_observation`` and ``tasks.observation.build_observation``
    info            ``Navigate._update_info``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from common import machine  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim import environment  # noqa: E402
from deck_sim.behaviour import MoverBehaviour  # noqa: E402
from deck_sim.control import mpc_predictor  # noqa: E402
from deck_sim.tasks import movers, navigate, physics_step, rewards  # noqa: E402

PHASES = (
    "composer",
    "observation",
    "action check",
    "tracker",
    "task hooks",
    "movers",
    "behaviour",
    "routes",
    "mj_step",
    "substeps",
    "contacts",
    "divergence",
    "read state",
    "surface",
    "prediction",
    "casadi",
    "clearances",
    "reward",
    "obs build",
    "info",
)


_INHERITED = object()


class PhaseTimer:
    """Nested ``perf_counter`` timers: every wrapped call adds its own time (callees' subtracted) to its phase.

    Calls made outside a timed ``env.step`` (resets) are not counted."""

    def __init__(self) -> None:
        self.own: dict[str, float] = defaultdict(float)
        """Seconds of own time per phase in the step being timed."""
        self.steps: list[dict[str, float]] = []
        """``own`` of every finished step."""
        self._stack: list[float] = []  # callees' time of every open call
        self._patched: list[tuple[Any, str, Any]] = []

    def wrap(self, phase: str, fn: Callable, root: bool = False) -> Callable:
        """``fn`` timed into ``phase``; a ``root`` call starts the counting, any other counts only inside one."""
        stack, own, clock = self._stack, self.own, time.perf_counter

        def timed(*args: Any, **kwargs: Any) -> Any:
            if not stack and not root:
                return fn(*args, **kwargs)
            t0 = clock()
            stack.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = clock() - t0
                own[phase] += elapsed - stack.pop()
                if stack:
                    stack[-1] += elapsed

        return timed

    def finish_step(self) -> None:
        """File the current step's phase times in ``steps`` and start the next step's."""
        self.steps.append(dict(self.own))
        self.own.clear()

    def patch(self, owner: Any, name: str, phase: str, root: bool = False) -> None:
        """Replace ``owner.name`` by its timed version (undone by ``unpatch``); nothing if it has none."""
        if not hasattr(owner, name):
            return
        # a class's own attribute, or _INHERITED (put back by deleting the wrapper)
        original = owner.__dict__.get(name, _INHERITED) if isinstance(owner, type) else getattr(owner, name)
        self._patched.append((owner, name, original))
        setattr(owner, name, self.wrap(phase, getattr(owner, name), root))

    def unpatch(self) -> None:
        """Put every patched attribute back."""
        for owner, name, original in reversed(self._patched):
            if original is _INHERITED:
                delattr(owner, name)
            else:
                setattr(owner, name, original)
        self._patched.clear()


def instrument(timer: PhaseTimer) -> None:
    """Wrap the phases' functions at module and class level (before an environment is made: composer keeps the
    task's bound hooks)."""
    timer.patch(environment.DeckEnvironment, "step", "composer", root=True)
    timer.patch(environment._PlainUpdater, "get_observation", "observation")
    timer.patch(mujoco, "mj_step", "mj_step")
    timer.patch(navigate, "checked_action", "action check")
    timer.patch(navigate, "track_displacement", "tracker")
    timer.patch(navigate, "track_velocity", "tracker")
    timer.patch(navigate.Navigate, "before_step", "task hooks")
    timer.patch(navigate.Navigate, "after_step", "task hooks")
    timer.patch(movers.MoverDriver, "command", "movers")
    timer.patch(MoverBehaviour, "command", "behaviour")
    timer.patch(MoverBehaviour, "command_lists", "behaviour")
    timer.patch(MoverBehaviour, "_depart", "routes")
    fused = physics_step.FusedStepper
    for name, phase in (
        ("substeps", "substeps"),
        ("check_contacts", "contacts"),
        ("diverged", "divergence"),
        ("read_state", "read state"),
        ("surface", "surface"),
    ):
        timer.patch(fused, name, phase)
    timer.patch(navigate.Navigate, "_predict", "prediction")
    timer.patch(mpc_predictor.MPCPredictor, "predict", "prediction")
    timer.patch(physics_step.Clearances, "__call__", "clearances")
    for name in ("attraction", "repulsion", "total_reward"):
        timer.patch(rewards, name, "reward")
    timer.patch(navigate.Navigate, "_update_observation", "obs build")
    timer.patch(navigate, "build_observation", "obs build")
    timer.patch(navigate.Navigate, "_update_info", "info")
    # the compiled Function's run: wrapped on every batch the predictor makes
    make_batch = mpc_predictor.MPCPredictor.__dict__["_batch"]

    def timed_batch(self: mpc_predictor.MPCPredictor, n: int) -> Any:
        batch = make_batch(self, n)
        if not getattr(batch.run, "_timed", False):
            batch.run = timer.wrap("casadi", batch.run)
            batch.run._timed = True
        return batch

    timer._patched.append((mpc_predictor.MPCPredictor, "_batch", make_batch))
    mpc_predictor.MPCPredictor._batch = timed_batch


def drive(env: Any, steps: int, seed: int, stepped: Callable[[], None] = lambda: None) -> list[float]:
    """Seconds of each of ``steps`` control steps after 50 unmeasured ones (resets not counted); ``stepped`` is
    called after every step."""
    rng = np.random.default_rng(seed)
    env.reset()
    times = []
    action = np.array([0.8, 0.0])
    for i in range(steps + 50):
        action = np.clip(0.8 * action + 0.2 * rng.uniform(-1, 1, 2) + np.array([0.1, 0.0]), -1, 1)
        t0 = time.perf_counter()
        ts = env.step(action)
        dt = time.perf_counter() - t0
        if i >= 50:
            times.append(dt)
        stepped()
        if ts.last():
            env.reset()
    return times


def profile_scene(name: str, steps: int, predictor: str, seed: int = 0) -> dict[str, Any]:
    """Own time per control step of every phase (s, mean and median over the steps), the time above raw
    ``mj_step`` and the Python's (above it, less the CasADi Function's; mean and median, s), the instrumented and
    plain step times (s), substeps."""
    timer = PhaseTimer()
    plain = deck_sim.load(name, seed=seed, episode__predictor=predictor)
    instrument(timer)
    try:
        env = deck_sim.load(name, seed=seed, episode__predictor=predictor)
        timed = drive(env, steps, seed, timer.finish_step)
    finally:
        timer.unpatch()
    untimed = drive(plain, steps, seed)
    measured = timer.steps[50:]
    phases = sorted({k for step in measured for k in step})
    above = [sum(step.values()) - step.get("mj_step", 0.0) for step in measured]
    python = [a - step.get("casadi", 0.0) for a, step in zip(above, measured, strict=True)]
    return {
        "above": (float(np.mean(above)), float(np.median(above))),
        "python": (float(np.mean(python)), float(np.median(python))),
        "mean": {k: float(np.mean([step.get(k, 0.0) for step in measured])) for k in phases},
        "median": {k: float(np.median([step.get(k, 0.0) for step in measured])) for k in phases},
        "timed": float(np.mean(timed)),
        "plain": float(np.mean(untimed)),
        "plain_median": float(np.median(untimed)),
        "substeps": env.task.n_substeps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--predictor", default="mpc")
    args = parser.parse_args()
    print(f"machine: {machine(mujoco=mujoco.__version__)}")
    print(f"predictor: {args.predictor}; means over {args.steps} control steps; us per control step (own time)")
    for name in args.scenes.split(","):
        r = profile_scene(name, args.steps, args.predictor)
        mean, median = r["mean"], r["median"]
        total = sum(mean.values())
        print(
            f"\n{name}: {r['substeps']} substeps; instrumented step {r['timed'] * 1e6:.0f} us, plain step mean "
            f"{r['plain'] * 1e6:.0f} us (median {r['plain_median'] * 1e6:.0f}); load {os.getloadavg()[0]:.2f}"
        )
        print(f"  {'phase':14s} {'mean us':>8s} {'share':>6s} {'median us':>10s}")
        for phase in PHASES:
            if phase in mean:
                print(f"  {phase:14s} {mean[phase] * 1e6:8.1f} {mean[phase] / total:6.1%} {median[phase] * 1e6:10.1f}")
        print(f"  {'all':14s} {total * 1e6:8.1f}")
        for label, key in (("above mj_step", "above"), ("Python", "python")):
            print(f"  {label:14s} {r[key][0] * 1e6:8.1f} {r[key][0] / total:6.1%} {r[key][1] * 1e6:10.1f}")


if __name__ == "__main__":
    main()
