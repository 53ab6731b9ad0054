"""Where a MuJoCo physics step's time goes in each scene, and what candidate model changes would save.

Every scene runs control steps with a seeded random policy (forward-biased, as ``step_speed.py`` does) and keeps the
physics state before each one; raw ``mujoco.mj_step(nstep=substeps)`` is then replayed from those states, so every
figure describes the states the task really meets.

Profile (the default), per scene:

- the physics step time with no instrumentation (the floor ``step_speed.py`` quotes, per substep and per 0.5 s
  control step);
- MuJoCo's own timers (``mjData.timer``): MuJoCo records them only while a time callback is set (``mjcb_time``);
  here ``time.perf_counter``, whose calls cost a little of their own (the instrumented step time is printed too);
- per substep: contacts, constraint rows, constraint islands and Newton iterations; contacts by the kinds of the two
  geoms; the collision geom pairs at each stage of MuJoCo's filtering (the body pairs the broadphase passes, the geom
  pairs then tested by contype/conaffinity, those within bounding distance, which reach a narrowphase collider),
  counted by a contact-filter callback that applies MuJoCo's own contype/conaffinity test, so nothing changes.

``--profile-variant NAME`` profiles a variant's model instead. ``--variants`` steps the same states in the scene's
model and in a changed copy, interleaved (the order alternates), and prints each variant's time ratio to the scene's
model (the median over states of the per-state ratio, and the ratio of the summed times, which a loaded machine's
outliers sway) and how many control steps end bit-identical (qpos and qvel). Two compiled copies of one model differ
by a percent or two in speed: smaller ratios are noise. ``--honesty`` adds the checks of
``tests/test_physics_honesty.py`` run on every changed model: turning radius and stopping distance of the aircraft
and the tractor against the current models' values and, for the variants that keep the scenes' timestep (the scenes
refuse others), contact with every obstacle kind named and no MuJoCo warnings over random episodes.

    python benchmarks/physics_profile.py [--scenes deck1,deck2,square] [--steps 400] [--repeat 3]
                                         [--variants [NAME,...]] [--honesty] [--honesty-episodes 100]
                                         [--profile-variant NAME]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from common import machine  # noqa: E402
from dm_control import mjcf  # noqa: E402

import deck_sim  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # test_physics_honesty

_STATE = ("qpos", "qvel", "act", "ctrl", "qacc_warmstart")
_T = mujoco.mjtTimer
# (label, timer, indent): the timers nest as MuJoCo's step calls them
_TIMERS = [
    ("step", _T.mjTIMER_STEP, 0),
    ("forward", _T.mjTIMER_FORWARD, 1),
    ("position", _T.mjTIMER_POSITION, 2),
    ("kinematics", _T.mjTIMER_POS_KINEMATICS, 3),
    ("inertia", _T.mjTIMER_POS_INERTIA, 3),
    ("collision", _T.mjTIMER_POS_COLLISION, 3),
    ("broadphase", _T.mjTIMER_COL_BROAD, 4),
    ("narrowphase", _T.mjTIMER_COL_NARROW, 4),
    ("make constraints", _T.mjTIMER_POS_MAKE, 3),
    ("project constraints", _T.mjTIMER_POS_PROJECT, 3),
    ("velocity", _T.mjTIMER_VELOCITY, 2),
    ("actuation", _T.mjTIMER_ACTUATION, 2),
    ("constraint solver", _T.mjTIMER_CONSTRAINT, 2),
    ("advance (integrate)", _T.mjTIMER_ADVANCE, 1),
]


def random_policy_states(name: str, steps: int, seed: int = 0) -> tuple[object, list[dict[str, np.ndarray]]]:
    """Run ``steps`` control steps of scene ``name`` with the forward-biased random policy of ``step_speed.py``;
    return the environment and the physics state before every step (``get_state``, with the model's body poses:
    the task places the static props and the pedestrians' frames in the model each episode)."""
    env = deck_sim.load(name, seed=seed, episode__predictor="none")
    rng = np.random.default_rng(seed)
    env.reset()  # compiles the physics: take its data after the first reset
    m, d = env.physics.model.ptr, env.physics.data.ptr
    states = []
    action = np.array([0.8, 0.0])
    for _ in range(steps):
        action = np.clip(0.8 * action + 0.2 * rng.uniform(-1, 1, 2) + np.array([0.1, 0.0]), -1, 1)
        st = get_state(d)
        st.update(body_pos=m.body_pos.copy(), body_quat=m.body_quat.copy(), geom_xpos=d.geom_xpos.copy(),
                  geom_xmat=d.geom_xmat.copy())
        states.append(st)
        if env.step(action).last():
            env.reset()
    return env, states


def get_state(d: mujoco.MjData) -> dict[str, np.ndarray]:
    """Copies of what ``mj_step`` reads from ``d`` in these models (no mocap bodies, no equality constraints)."""
    st = {f: np.copy(getattr(d, f)) for f in _STATE}
    st["time"] = np.array(d.time)
    return st


def set_state(d: mujoco.MjData, st: dict[str, np.ndarray], m: mujoco.MjModel | None = None) -> None:
    """Write a ``get_state`` copy into ``d`` (and, given its model ``m``, the recorded body poses into ``m``)."""
    if m is not None:
        m.body_pos[:] = st["body_pos"]
        m.body_quat[:] = st["body_quat"]
    for f in _STATE:
        getattr(d, f)[:] = st[f]
    d.time = float(st["time"])


# -- the profile ------------------------------------------------------------------------------------------------


def geom_kinds(m: mujoco.MjModel) -> list[str]:
    """A kind per geom: ``surface`` (the deck or the plaza), ``wheel`` (wheels and casters), the arena's own geoms by
    name (``island``), else the kind of entity that owns it (``agent``, ``tractor``, ``taxiing``, ``parked``,
    ``kiosk``, ``group``, ``pedestrian``)."""
    kinds = []
    for g in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
        owner = name.split("/")[0] if "/" in name else ""
        if m.geom_contype[g] == 2:
            kinds.append("wheel")
        elif name == "surface":
            kinds.append("surface")
        elif not owner:
            kinds.append(name or "world")
        else:
            for prefix, kind in (
                ("agent", "agent"),
                ("tractor", "tractor"),
                ("taxiing", "taxiing"),
                ("parked", "parked"),
                ("kiosk", "kiosk"),
                ("crowd", "group"),
                ("pedestrian", "pedestrian"),
            ):
                if owner.startswith(prefix):
                    kinds.append(kind)
                    break
            else:
                kinds.append(owner)
    return kinds


@dataclass
class _PairCounter:
    """A contact-filter callback that counts the geom pairs MuJoCo's collision pass hands its filter and applies
    MuJoCo's own contype/conaffinity test, so the physics is unchanged."""

    tested: int = 0
    passed: int = 0
    near: int = 0
    bodies: set[tuple[int, int]] = field(default_factory=set)

    def __call__(self, m: mujoco.MjModel, d: mujoco.MjData, g1: int, g2: int) -> int:
        self.tested += 1
        self.bodies.add((int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])))
        filtered = not (m.geom_contype[g1] & m.geom_conaffinity[g2]) and not (
            m.geom_contype[g2] & m.geom_conaffinity[g1]
        )
        if not filtered:
            self.passed += 1
            # MuJoCo's bounding-sphere test (no margins in these models; no planes): pairs that reach a collider
            r = m.geom_rbound[g1] + m.geom_rbound[g2]
            dx = d.geom_xpos[g1] - d.geom_xpos[g2]
            if m.geom_rbound[g1] > 0 and m.geom_rbound[g2] > 0 and float(dx @ dx) <= r * r:
                self.near += 1
        return int(filtered)


def profile_scene(name: str, steps: int, repeat: int, variant: Variant | None = None) -> None:
    """Print the timer breakdown and the contact statistics of scene ``name`` (with ``variant`` applied)."""
    env, states = random_policy_states(name, steps)
    n_sub = env.task.n_substeps
    if variant is None:
        m, w = env.physics.model.ptr, mujoco.MjData(env.physics.model.ptr)

        def put(st: dict[str, np.ndarray]) -> None:
            set_state(w, st, m)
    else:
        prep = Prepared(name, variant, env.physics.model.ptr)
        m, w, put = prep.model, prep.data, prep.set_state
    # un-instrumented floor, then the timers, interleaved per state
    floor, instrumented = [], []
    per_state = []  # timer durations of every replayed control step, seconds
    for _ in range(repeat):
        for st in states:
            put(st)
            t0 = time.perf_counter()
            mujoco.mj_step(m, w, nstep=n_sub)
            floor.append(time.perf_counter() - t0)
            put(st)
            for t in range(int(_T.mjNTIMER)):
                w.timer[t].duration = 0.0
                w.timer[t].number = 0
            mujoco.set_mjcb_time(time.perf_counter)
            try:
                t0 = time.perf_counter()
                mujoco.mj_step(m, w, nstep=n_sub)
                instrumented.append(time.perf_counter() - t0)
            finally:
                mujoco.set_mjcb_time(None)
            per_state.append([w.timer[int(t)].duration for _, t, _ in _TIMERS])
    # medians over control steps (a loaded machine's outliers would dominate means), per physics step
    per_step = np.median(np.array(per_state), axis=0) / n_sub * 1e6
    floor_us = float(np.median(floor)) / n_sub * 1e6
    print(
        f"\n## {name}{f' ({variant.name})' if variant else ''}: {n_sub} substeps of {m.opt.timestep:.5f} s; "
        f"{m.nbody} bodies, {m.ngeom} geoms "
        f"({int(((m.geom_contype | m.geom_conaffinity) > 0).sum())} collidable), nv {m.nv}"
    )
    print(
        f"mj_step {floor_us:.1f} us (median, no instrumentation) = {floor_us * n_sub / 1e3:.3f} ms per control step; "
        f"with the timers' callback {float(np.median(instrumented)) / n_sub * 1e6:.1f} us"
    )
    print(f"{'timer (median per step)':32s} {'us/step':>8s} {'share':>6s}")
    for (label, _, indent), us in zip(_TIMERS, per_step, strict=True):
        print(f"{'  ' * indent + label:32s} {us:8.2f} {100 * us / per_step[0]:5.1f}%")
    rest = per_step[1] - per_step[2] - per_step[10] - per_step[11] - per_step[12]
    print(f"{'    (rest: acceleration, sensors)':32s} {rest:8.2f} {100 * rest / per_step[0]:5.1f}%")
    stats_scene(m, w, put, n_sub, states)


def stats_scene(
    m: mujoco.MjModel,
    w: mujoco.MjData,
    put: Callable[[dict[str, np.ndarray]], None],
    n_sub: int,
    states: list[dict[str, np.ndarray]],
) -> None:
    """Print per-substep contact, constraint and collision-pair statistics over the states (written into ``w`` by
    ``put``), ``n_sub`` substeps from each."""
    kinds = geom_kinds(m)
    counter = _PairCounter()
    ncon, nefc, nisland, niter, body_pairs = [], [], [], [], []
    by_kind: Counter = Counter()
    mujoco.set_mjcb_contactfilter(counter)
    try:
        for st in states:
            put(st)
            for _ in range(n_sub):
                counter.bodies.clear()
                mujoco.mj_step(m, w)
                body_pairs.append(len(counter.bodies))
                ncon.append(w.ncon)
                nefc.append(w.nefc)
                nisland.append(w.nisland)
                niter.append(w.solver_niter[: w.nisland].tolist())
                for g1, g2 in w.contact.geom[: w.ncon].tolist():
                    by_kind["-".join(sorted((kinds[g1], kinds[g2])))] += 1
    finally:
        mujoco.set_mjcb_contactfilter(None)
    n = len(ncon)
    iters = [i for step in niter for i in step] or [0]
    print(
        f"per substep: contacts {np.mean(ncon):.1f} (max {max(ncon)}), constraint rows {np.mean(nefc):.1f}, "
        f"constraint islands {np.mean(nisland):.1f}, Newton iterations per island {np.mean(iters):.2f} "
        f"(max {max(iters)}), summed over islands {np.mean([sum(s) for s in niter]):.1f}"
    )
    print(
        f"collision pairs per substep: body pairs past the broadphase and body bitmask {np.mean(body_pairs):.1f}; "
        f"geom pairs tested by contype/conaffinity {counter.tested / n:.1f}, passing {counter.passed / n:.1f}, "
        f"within bounding spheres (collider called) {counter.near / n:.1f}"
    )
    print("contacts per substep by kind: " + ", ".join(f"{k} {v / n:.2f}" for k, v in by_kind.most_common()))


# -- variants ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Variant:
    """A candidate change: an edit of the composed MJCF before compiling and/or of the compiled model's options."""

    name: str
    what: str
    mjcf_edit: Callable[[mjcf.RootElement], None] | None = None
    model_edit: Callable[[mujoco.MjModel], None] | None = None
    timestep: float | None = None  # None: the scene's


def _opt(**kw: object) -> Callable[[mujoco.MjModel], None]:
    def edit(m: mujoco.MjModel) -> None:
        for k, v in kw.items():
            setattr(m.opt, k, v)

    return edit


def _flags(disable: int = 0, enable: int = 0) -> Callable[[mujoco.MjModel], None]:
    def edit(m: mujoco.MjModel) -> None:
        m.opt.disableflags |= disable
        m.opt.enableflags |= enable

    return edit


def _both(*edits: Callable[[mujoco.MjModel], None]) -> Callable[[mujoco.MjModel], None]:
    def edit(m: mujoco.MjModel) -> None:
        for e in edits:
            e(m)

    return edit


def _geoms(body: mjcf.Element) -> list[mjcf.Element]:
    return [c for c in body.all_children() if c.tag == "geom"]


def _bodies(root: mjcf.RootElement) -> list[mjcf.Element]:
    """Every body of the composed model except the attachment frames (which have no name of their own)."""
    return [b for b in root.find_all("body") if getattr(b, "name", None)]


def _is_visual(g: mjcf.Element) -> bool:
    return g.dclass is not None and g.dclass.dclass in ("visual", "marking")


def statics_in_world(root: mjcf.RootElement) -> None:
    """Move every static prop's collision geoms into the world body as ``static_<k>`` (one static body for all of
    them; ``Prepared`` places them where the episode put the props). Their visual geoms stay in the props' bodies,
    which then collide with nothing."""
    k = 0
    for body in _bodies(root):
        if body.name not in ("parked_aircraft", "kiosk", "crowd_group"):
            continue
        for g in _geoms(body):
            if _is_visual(g):
                continue
            # the geom's shape and its collision class's bits; ``Prepared`` sets its pose for every state
            attrs = {
                "type": g.type,
                "size": g.size,
                "fromto": g.fromto,
                "contype": 4,
                "conaffinity": 4,
                "group": 3,
                "mass": 0,
            }
            g.remove()
            root.worldbody.add("geom", name=f"static_{k}", **{a: v for a, v in attrs.items() if v is not None})
            k += 1


def deck_plane(root: mjcf.RootElement) -> None:
    """The surface as a plane (an infinite deck) instead of its box."""
    surface = root.find("geom", "surface")
    if surface.dclass.dclass != "surface" or root.find("body", "deck") is None:
        return
    surface.type = "plane"
    surface.pos = [float(surface.pos[0]), float(surface.pos[1]), 0.0]
    surface.size = [float(surface.size[0]), float(surface.size[1]), 0.1]


def parked_one_box(root: mjcf.RootElement) -> None:
    """A parked aircraft's four collision geoms as the one box around them (its planar footprint, 4.3 m high)."""
    for body in _bodies(root):
        if body.name != "parked_aircraft":
            continue
        for g in _geoms(body):
            if not _is_visual(g):
                g.remove()
        body.add("geom", name="hull", dclass=body.root.default.find("default", "collision"), type="box",
                 pos=[-0.05, 0, 2.15], size=[9.15, 4.95, 2.15])


def visual_in_collision_bodies(root: mjcf.RootElement) -> None:
    """Move the geoms of every ``*_visual`` body into its parent body, beside the collision geoms (what the visual
    bodies save)."""
    for body in _bodies(root):
        if body.name.endswith("_visual"):
            parent = body.parent
            for g in _geoms(body):
                attrs = g.get_attributes()
                g.remove()
                parent.add("geom", **attrs)
            body.remove()


def no_accelerometer(root: mjcf.RootElement) -> None:
    """Drop the aircraft's accelerometers (no part of the task reads them; they make MuJoCo run its post-constraint
    pass wherever sensors are computed)."""
    for sensor in root.find_all("sensor"):
        if sensor.tag == "accelerometer":
            sensor.remove()


def island_body(root: mjcf.RootElement) -> None:
    """The island's collision box in a child body of its own, so the deck surface's body touches only wheels."""
    island = root.find("geom", "island")
    if island is None:  # the square has no island
        return
    attrs = island.get_attributes()
    island.remove()
    root.find("body", "deck").add("body", name="island").add("geom", **attrs)


VARIANTS = [
    Variant("visual-in-collision", "visual geoms back in the bodies of the collision geoms",
            mjcf_edit=visual_in_collision_bodies),
    Variant("no-accelerometer", "the aircraft without its unused accelerometer", mjcf_edit=no_accelerometer),
    Variant("island-body", "the island in a body of its own", mjcf_edit=island_body),
    Variant("statics-in-world", "static props' geoms in the world body", mjcf_edit=statics_in_world),
    Variant("deck-plane", "deck surface a plane, not a box", mjcf_edit=deck_plane),
    Variant("parked-1-box", "parked aircraft: one collision box, not 4 geoms", mjcf_edit=parked_one_box),
    Variant("no-islands", "constraint islands off", model_edit=_flags(disable=int(mujoco.mjtDisableBit.mjDSBL_ISLAND))),
    Variant("sleep", "sleeping bodies on", model_edit=_flags(enable=int(mujoco.mjtEnableBit.mjENBL_SLEEP))),
    Variant(
        "sleep-0",
        "sleep on, tolerance 0 (no tree falls asleep)",
        model_edit=_both(_flags(enable=int(mujoco.mjtEnableBit.mjENBL_SLEEP)), _opt(sleep_tolerance=0.0)),
    ),
    Variant(
        "dense+no-islands",
        "dense Jacobians, islands off",
        model_edit=_both(
            _opt(jacobian=int(mujoco.mjtJacobian.mjJAC_DENSE)), _flags(disable=int(mujoco.mjtDisableBit.mjDSBL_ISLAND))
        ),
    ),
    Variant("pyramidal", "pyramidal friction cones", model_edit=_opt(cone=int(mujoco.mjtCone.mjCONE_PYRAMIDAL))),
    Variant("cg", "CG solver", model_edit=_opt(solver=int(mujoco.mjtSolver.mjSOL_CG))),
    Variant("pgs", "PGS solver", model_edit=_opt(solver=int(mujoco.mjtSolver.mjSOL_PGS))),
    Variant("iter-4", "4 solver iterations", model_edit=_opt(iterations=4)),
    Variant("iter-2", "2 solver iterations", model_edit=_opt(iterations=2)),
    Variant("tol-1e-5", "solver tolerance 1e-5", model_edit=_opt(tolerance=1e-5)),
    Variant("ls-3", "3 line-search iterations", model_edit=_opt(ls_iterations=3)),
    Variant("dense", "dense Jacobians", model_edit=_opt(jacobian=int(mujoco.mjtJacobian.mjJAC_DENSE))),
    Variant("sparse", "sparse Jacobians", model_edit=_opt(jacobian=int(mujoco.mjtJacobian.mjJAC_SPARSE))),
    Variant("dt-1/24", "timestep 1/24 s (12 substeps)", timestep=1 / 24),
]


class Prepared:
    """Scene ``name``'s composed model with variant ``v`` applied, compiled, at the scene's (or the variant's)
    timestep, and the maps that carry a recorded state of the scene's model ``base`` into it."""

    def __init__(self, name: str, v: Variant, base: mujoco.MjModel) -> None:
        env = deck_sim.load(name, seed=0, episode__predictor="none")
        root = env.task.root_entity.mjcf_model
        if v.mjcf_edit is not None:
            v.mjcf_edit(root)
        self.physics = mjcf.Physics.from_mjcf_model(root)
        m = self.model = self.physics.model.ptr
        m.opt.timestep = v.timestep or env.task.spec.episode.physics_timestep
        if v.model_edit is not None:
            v.model_edit(m)
        self.data = mujoco.MjData(m)
        body = mujoco.mjtObj.mjOBJ_BODY
        pairs = [(b, mujoco.mj_name2id(m, body, mujoco.mj_id2name(base, body, b))) for b in range(1, base.nbody)]
        self._bodies = np.array([p for p in pairs if p[1] >= 0], dtype=int).reshape(-1, 2)
        # statics moved into the world body: static_<k> is the k-th static collision geom of the base model
        kinds = geom_kinds(base)
        static = [g for g in range(base.ngeom) if kinds[g] in ("parked", "kiosk", "group") and base.geom_contype[g]]
        moved = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"static_{k}") for k in range(len(static))]
        self._statics = [(b, g) for b, g in zip(static, moved, strict=True) if g >= 0]

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        """Write a state recorded on the base model into this model and its data."""
        m = self.model
        m.body_pos[self._bodies[:, 1]] = st["body_pos"][self._bodies[:, 0]]
        m.body_quat[self._bodies[:, 1]] = st["body_quat"][self._bodies[:, 0]]
        for b, g in self._statics:
            m.geom_pos[g] = st["geom_xpos"][b]
            mujoco.mju_mat2Quat(m.geom_quat[g], st["geom_xmat"][b])
        set_state(self.data, st)


def compare_variants(name: str, variants: list[Variant], steps: int, repeat: int) -> None:
    """Print each variant's physics time per control step as a ratio to the scene's model, from the same states."""
    env, states = random_policy_states(name, steps)
    m = env.physics.model.ptr
    n_sub = env.task.n_substeps
    period = env.task.spec.episode.control_period
    built = [Prepared(name, v, m) for v in variants]
    w0 = mujoco.MjData(m)
    print(f"\n## {name}: {len(states)} states x {repeat}; base {n_sub} substeps of {m.opt.timestep:.5f} s")
    print(f"{'variant':20s} {'ratio':>6s} {'(sums)':>6s} {'base ms':>8s} {'var ms':>7s} {'identical':>10s}  what")
    for v, prep in zip(variants, built, strict=True):
        mv, wv = prep.model, prep.data
        nv_sub = int(round(period / mv.opt.timestep))
        tb, tv, same = [], [], 0
        for r in range(repeat):
            for i, st in enumerate(states):
                order = (0, 1) if (i + r) % 2 == 0 else (1, 0)
                for which in order:
                    if which == 0:
                        mm, ww, ns, out = m, w0, n_sub, tb
                        set_state(w0, st, m)
                    else:
                        mm, ww, ns, out = mv, wv, nv_sub, tv
                        prep.set_state(st)
                    t0 = time.perf_counter()
                    mujoco.mj_step(mm, ww, nstep=ns)
                    out.append(time.perf_counter() - t0)
                same += np.array_equal(w0.qpos, wv.qpos) and np.array_equal(w0.qvel, wv.qvel)
        ratio = float(np.median(np.array(tv) / np.array(tb)))
        sums = sum(tv) / sum(tb)
        ident = f"{same}/{len(tb)}" if nv_sub == n_sub else "n/a"
        print(
            f"{v.name:20s} {ratio:6.3f} {sums:6.3f} {np.median(tb) * 1e3:8.3f} {np.median(tv) * 1e3:7.3f} "
            f"{ident:>10s}  {v.what} (load {os.getloadavg()[0]:.2f})"
        )


def honesty_of(variants: list[Variant], scenes: list[str], episodes: int) -> None:
    """Run ``tests/test_physics_honesty.py``'s checks on every variant (and on today's model, first)."""
    import test_physics_honesty as honesty

    print("\n## honesty: turning radius and stopping distance against the current models' references (within "
          f"{honesty.TOLERANCE:.0%}), contacts named, warnings over {episodes} random episodes per scene")
    for v in [Variant("today", "the shipped models"), *variants]:
        motion = honesty.measure_motion(mjcf_edit=v.mjcf_edit, model_edit=v.model_edit, timestep=v.timestep)
        errs = {k: motion[k] / honesty.REFERENCE[k] - 1.0 for k in honesty.REFERENCE}
        worst = max(abs(e) for e in errs.values())
        line = ", ".join(f"{k} {motion[k]:.3f} ({e:+.1%})" for k, e in errs.items())
        named = warned = "-"  # the scenes refuse a timestep other than their own
        if v.timestep is None:
            missed = [
                f"{s}:{k}"
                for s in scenes
                for k, ok in honesty.contacts_named(s, mjcf_edit=v.mjcf_edit, model_edit=v.model_edit).items()
                if not ok
            ]
            named = "all" if not missed else "missed " + " ".join(missed)
            warned = ", ".join(
                f"{s} {honesty.random_episode_warnings(s, episodes, mjcf_edit=v.mjcf_edit, model_edit=v.model_edit)}"
                for s in scenes
            )
        verdict = "within" if worst <= honesty.TOLERANCE else "OUTSIDE"
        print(f"{v.name:18s} {verdict} {worst:.1%}: {line}; contacts named: {named}; warnings: {warned}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--steps", type=int, default=400, help="control steps of the random policy per scene")
    parser.add_argument("--repeat", type=int, default=3, help="replays of every state")
    parser.add_argument(
        "--variants",
        nargs="?",
        const="all",
        help="compare candidate changes instead of profiling: 'all' or names, comma-separated: "
        + ", ".join(v.name for v in VARIANTS),
    )
    parser.add_argument("--honesty", action="store_true", help="with --variants: run the honesty checks on each")
    parser.add_argument("--profile-variant", help="profile the scenes with this variant applied")
    parser.add_argument("--honesty-episodes", type=int, default=100)
    args = parser.parse_args()
    scenes = args.scenes.split(",")
    print(f"machine: {machine(mujoco=mujoco.__version__)}")
    print(f"load average (1 min) at start: {os.getloadavg()[0]:.2f}")
    if args.variants:
        chosen = VARIANTS if args.variants == "all" else [v for v in VARIANTS if v.name in args.variants.split(",")]
        for name in scenes:
            compare_variants(name, chosen, args.steps, args.repeat)
        if args.honesty:
            honesty_of(chosen, scenes, args.honesty_episodes)
    else:
        variant = next((v for v in VARIANTS if v.name == args.profile_variant), None)
        if args.profile_variant and variant is None:
            parser.error(f"no variant {args.profile_variant!r}")
        for name in scenes:
            profile_scene(name, args.steps, args.repeat, variant)
    print(f"\nload average (1 min) at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
