"""The physics of one control step: fused ``mj_step`` substeps, contact checks, divergence, surface and clearances.

composer sees a single substep per control step (its per-substep Python would otherwise cost a few times the
physics; ``benchmarks/step_speed.py`` measures the step against raw ``mj_step``). ``FusedStepper.substeps`` runs
all the others as ``mj_step(nstep)`` calls, split ``episode.collision_checks`` times to look for contacts
between the agent and the obstacles; composer runs the last one.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from dm_control import mjcf

from deck_sim.entities import Aircraft, Pedestrian, StaticProp, Tractor
from deck_sim.geometry import Footprints
from deck_sim.scenes.arena_facts import vehicle_top_speeds

if TYPE_CHECKING:
    from deck_sim.entities.arenas import _SiteArena

_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
)

_NO_SENSORS = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
"""The disable flag that skips sensor computation on the fused substeps between contact checks."""

RUNAWAY_FACTOR = 10.0
"""A vehicle faster than this many times the top speed of the fastest vehicle in the scene
(``scenes.arena_facts.vehicle_top_speeds``) has run away: the physics diverged, whether MuJoCo warned or not."""


def as_slice(ids: np.ndarray) -> slice | np.ndarray:
    """Indices ``ids`` as a slice where they are consecutive and increasing (numpy writes through a slice with
    less work than through an index array, the same values), else ``ids`` themselves."""
    ids = np.asarray(ids, dtype=int)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


class FusedStepper:
    """The compiled model's index tables for stepping and reading the vehicles, and the contact bookkeeping.

    Args:
        physics: the compiled physics.
        arena: the arena (its fixed obstacles' geoms and its surface).
        agents: the agents' entities (one, or several acting at once); their rows lead the state.
        movers: the movers' entities.
        statics: the static obstacles' entities.
        contact_sensors: each agent's contact sensor (how many contacts its own body has).
        n_substeps: physics steps per control step.
        collision_checks: contact checks per control step.
    """

    def __init__(
        self,
        physics: mjcf.Physics,
        arena: _SiteArena,
        agents: list[Aircraft | Pedestrian],
        movers: list[Tractor | Aircraft | Pedestrian],
        statics: list[StaticProp],
        contact_sensors: list[mjcf.Element],
        n_substeps: int,
        collision_checks: int,
    ) -> None:
        m = physics.model
        self._m, self._d = m.ptr, physics.data.ptr
        self._arena = arena
        if len(contact_sensors) != len(agents):
            raise ValueError(f"one contact sensor per agent: {len(agents)} agents, {len(contact_sensors)} sensors")
        self.n_agents = k = len(agents)
        """How many agents lead the state's rows."""
        vehicles = [*agents, *movers]
        self.body_ids = np.array([physics.bind(v.root_body).element_id for v in vehicles])
        """Body ids of the agents (first) and every mover."""
        # planar velocity dofs: free joints' linear x, y; pedestrians' slide joints
        vel_dofs = []
        for v in vehicles:
            if isinstance(v, Pedestrian):
                vel_dofs.append([int(physics.bind(j).dofadr) for j in v.joints])
            else:
                fj = mjcf.get_frame_freejoint(v.mjcf_model)
                adr = int(physics.bind(fj).dofadr)
                vel_dofs.append([adr, adr + 1])
        self._vel_dofs = np.array(vel_dofs, dtype=int)
        self._is_ped = np.array([isinstance(v, Pedestrian) for v in vehicles])
        self._all_ped = bool(self._is_ped.all())
        self._mover_ids = self.body_ids[k:]
        # views of MuJoCo's arrays (they live as long as the data and are written in place by every step)
        d = self._d
        self._xpos, self._xmat, self._qpos, self._qvel = d.xpos, d.xmat, d.qpos, d.qvel
        self._warning_number, self._sensordata = d.warning.number, d.sensordata
        top = vehicle_top_speeds()
        fastest = max(
            top["pedestrian" if isinstance(v, Pedestrian) else "aircraft" if isinstance(v, Aircraft) else "tractor"]
            for v in vehicles
        )
        self.runaway_speed = RUNAWAY_FACTOR * fastest
        """m/s: a planar speed above this flags the control step as diverged."""
        self._runaway_sq = self.runaway_speed**2
        self._any_ped = bool(self._is_ped.any())
        # contact bookkeeping: which geoms are each agent's, which obstacle owns every other geom (with several
        # agents, each is an obstacle to the others)
        self.obstacle_names = [p.mjcf_model.model for p in statics]
        """Names of the obstacles: the static ones (the arena's own last), then the movers, then (with several
        agents) the agents."""
        self.obstacle_names += [g.name for g in arena.fixed_obstacle_geoms]
        self.obstacle_names += [mv.mjcf_model.model for mv in movers]
        if k > 1:
            self.obstacle_names += [a.mjcf_model.model for a in agents]
        vehicle_obstacles = movers if k == 1 else [*movers, *agents]
        owner = np.full(m.ngeom, -1, dtype=int)
        k = 0
        for p in statics:
            owner[[physics.bind(g).element_id for g in p.mjcf_model.find_all("geom")]] = k
            k += 1
        for g in arena.fixed_obstacle_geoms:
            owner[physics.bind(g).element_id] = k
            k += 1
        for mv in vehicle_obstacles:
            owner[[physics.bind(g).element_id for g in mv.mjcf_model.find_all("geom")]] = k
            k += 1
        self._geom_owner = owner
        self._agent_geoms = []
        for a in agents:
            mask = np.zeros(m.ngeom, dtype=bool)
            mask[[physics.bind(g).element_id for g in a.mjcf_model.find_all("geom")]] = True
            self._agent_geoms.append(mask)
        self._contact_adrs = [int(physics.bind(c).adr) for c in contact_sensors]
        self._warning_ids = np.array([int(w) for w in _DIVERGENCE_WARNINGS])
        # the fused substeps (all but composer's last one), split for contact checks
        n_fused = n_substeps - 1
        edges = np.linspace(0, n_fused, collision_checks + 1).round().astype(int)
        self._chunks = [int(c) for c in np.diff(edges) if c > 0]
        self.collisions: list[str | None] = [None] * self.n_agents
        """The first obstacle each agent touched in the current control step, or None."""
        self._warnings_before = 0
        self._diverged = False  # what ``diverged`` found for the current control step

    @property
    def collided_with(self) -> str | None:
        """The first obstacle the (first) agent touched in the current control step, or None."""
        return self.collisions[0]

    def read_state(self) -> dict[str, np.ndarray]:
        """Planar pose and velocity of the agents (the first ``n_agents`` rows) and every mover: ``xy`` (k, 2)
        metres, ``yaw`` (k,) radians, ``vel`` (k, 2) m/s and ``forward_speed`` (k,) m/s; fresh arrays."""
        xy = self._xpos[self.body_ids, :2]  # (fancy indexing copies)
        xmat = self._xmat[self.body_ids]
        yaw = np.arctan2(xmat[:, 3], xmat[:, 0])
        vel = self._qvel[self._vel_dofs]
        # pedestrians have no body heading: their speed is the norm of their velocity (every row's when all
        # vehicles are pedestrians; the same call on the same arrays either way)
        if self._all_ped:
            fwd = np.hypot(vel[self._is_ped, 0], vel[self._is_ped, 1])
        else:
            fwd = vel[:, 0] * np.cos(yaw) + vel[:, 1] * np.sin(yaw)
            if self._any_ped:
                fwd[self._is_ped] = np.hypot(vel[self._is_ped, 0], vel[self._is_ped, 1])
        return {"xy": xy, "yaw": yaw, "vel": vel, "forward_speed": fwd}

    def start_episode(self) -> None:
        """Forget the last contacts and take MuJoCo's warning counts as they are now."""
        self.collisions = [None] * self.n_agents
        self._diverged = False
        self._warnings_before = sum(self._warning_number[self._warning_ids].tolist())

    def substeps(self) -> None:
        """Run the fused substeps (all but composer's last one), checking contacts after every chunk."""
        m, d = self._m, self._d
        self._warnings_before = sum(self._warning_number[self._warning_ids].tolist())  # compared in ``diverged``
        collisions = self.collisions = [None] * self.n_agents
        self._diverged = False
        sensordata, adrs = self._sensordata, self._contact_adrs
        # Sensors are read only at the end of a chunk (the contact sensor) and of the control step, and nothing in
        # the dynamics depends on them: skipping them on the steps in between (the accelerometer alone makes MuJoCo
        # run mj_rnePostConstraint every step) leaves the trajectory and every value read bit-identical.
        opt = m.opt
        flags = opt.disableflags
        for c in self._chunks:
            if c > 1:
                opt.disableflags = flags | _NO_SENSORS
                try:
                    mujoco.mj_step(m, d, nstep=c - 1)
                finally:
                    opt.disableflags = flags
            mujoco.mj_step(m, d, nstep=1)
            for c_i, adr in zip(collisions, adrs):  # noqa: B905 - one per agent by construction
                if c_i is None and sensordata[adr] != 0.0:
                    self.check_contacts()
                    break

    def check_contacts(self) -> None:
        """Record the first obstacle each agent touches (contacts between bodies only; wheels touch the deck)."""
        d, geom = self._d, None
        for i, adr in enumerate(self._contact_adrs):
            if self.collisions[i] is not None or self._sensordata[adr] == 0.0:
                continue
            if geom is None:
                geom = d.contact.geom[: d.ncon]
            mine = self._agent_geoms[i]
            a0, a1 = mine[geom[:, 0]], mine[geom[:, 1]]
            other = np.where(a0, geom[:, 1], geom[:, 0])[a0 ^ a1]
            owners = self._geom_owner[other]
            owners = owners[owners >= 0]
            if len(owners):
                self.collisions[i] = self.obstacle_names[int(owners[0])]

    def diverged(self, vel: np.ndarray) -> bool:
        """Whether the physics diverged over the control step, composer's substep included: MuJoCo warned (and
        reset the state) after ``substeps`` began, a position is not finite, or a vehicle moves faster than
        ``runaway_speed`` (a timestep too coarse for the models can blow up without MuJoCo noticing). ``vel`` is
        ``read_state()["vel"]`` of the state now."""
        warnings = sum(self._warning_number[self._warning_ids].tolist())
        speed_sq = float((vel * vel).sum(axis=1).max())
        qpos = self._qpos
        # (one reduction on the common path: a sum that is not finite sends it to the element-wise test)
        finite = math.isfinite(qpos.sum()) or bool(np.isfinite(qpos).all())
        self._diverged = warnings > self._warnings_before or not finite or not speed_sq <= self._runaway_sq
        return self._diverged

    def surface(self, xy: np.ndarray) -> tuple[list[bool], list[int]]:
        """Whether each agent is on the surface, and the indices of the movers that are lost: off the surface or
        fallen below it. ``xy`` (k + n, 2) is ``read_state()["xy"]``.

        After a control step that ``diverged`` found diverged, no mover counts as lost: the state is MuJoCo's reset
        (every body back at the origin, piled on each other) or a blown-up one, the episode ends, and there is
        nothing to rescue (``MoverDriver.rescue`` would log every mover as pushed off the surface)."""
        on_surface = self._arena.on_surface(xy).tolist()  # the agents, then every mover
        k = self.n_agents
        if self._diverged:
            return on_surface[:k], []
        z = self._xpos[self._mover_ids, 2].tolist()
        lost = [i for i, (on, zi) in enumerate(zip(on_surface[k:], z, strict=True)) if not on or zi < -1.0]
        return on_surface[:k], lost


class Clearances:
    """Clearance from the agent's disc to every static obstacle and mover over one episode, metres.

    Args:
        statics: the episode's static obstacles' footprints.
        mover_xy: (n, 2) the movers' start positions, metres.
        mover_half: (n, 2) the movers' footprint half-extents, metres.
        mover_radius: (n,) the movers' footprint rounding radii, metres.
        agent_radius: the agent's disc radius, metres.
    """

    def __init__(
        self,
        statics: Footprints,
        mover_xy: np.ndarray,
        mover_half: np.ndarray,
        mover_radius: np.ndarray,
        agent_radius: float,
    ) -> None:
        self.footprints = Footprints.concatenate(
            [  # statics, then movers (rows refreshed every step)
                statics,
                Footprints(mover_xy.copy(), mover_half.copy(), np.zeros(len(mover_xy)), mover_radius.copy()),
            ]
        )
        """Every obstacle's footprint, the static ones first; the movers' rows hold the last call's poses."""
        self._n_static = len(statics)
        self._half, self._radius = self.footprints.half.tolist(), self.footprints.radius.tolist()
        self._hx, self._hy = self.footprints.half[:, 0].copy(), self.footprints.half[:, 1].copy()
        self._r = self.footprints.radius.copy()
        self._agent_radius = agent_radius

    def __call__(self, st: dict[str, np.ndarray]) -> np.ndarray:
        """Clearance (k,) from the agent's disc to every static obstacle and mover for the state ``st``
        (``FusedStepper.read_state``), metres.

        ``Footprints.distance`` from one point, element-wise in numpy except the corner distances, which come
        from ``math.hypot`` (as ``_clearances_python``); equal to ``self.footprints.distance(agent)[0] - radius``
        to a few ulps (``math.hypot`` rounds differently). A state that is not finite (a blown-up one) takes the
        loop over plain floats instead, whose builtin ``max``/``min`` keep a NaN first argument only; with finite
        numbers both give the same floats.
        """
        fp, k, xy = self.footprints, self._n_static, st["xy"]
        fp.centers[k:] = xy[1:]  # movers' rows are updated in place (hot path)
        fp.yaw[k:] = st["yaw"][1:]
        c, s = np.cos(fp.yaw), np.sin(fp.yaw)
        if not math.isfinite(xy.sum() + fp.yaw.sum()):
            return self._clearances_python(xy[0].tolist(), c.tolist(), s.tolist())
        rel = xy[0] - fp.centers
        rx, ry = rel[:, 0], rel[:, 1]
        qx = np.abs(rx * c + ry * s) - self._hx
        qy = np.abs(-rx * s + ry * c) - self._hy
        outside = np.array(list(map(math.hypot, np.maximum(qx, 0.0).tolist(), np.maximum(qy, 0.0).tolist())))
        out = outside + np.minimum(np.maximum(qx, qy), 0.0) - self._r - self._agent_radius
        if math.isnan(out.sum()):  # (finite inputs whose differences overflow)
            return self._clearances_python(xy[0].tolist(), c.tolist(), s.tolist())
        return out

    def _clearances_python(self, agent_xy: list[float], cos: list[float], sin: list[float]) -> np.ndarray:
        """``__call__`` on plain floats, the footprints' rows already updated; ``cos`` and ``sin`` of their
        yaws."""
        fp = self.footprints
        px, py = agent_xy
        agent_r, hypot = self._agent_radius, math.hypot
        out = []
        for (cx, cy), (hx, hy), r, c, s in zip(fp.centers.tolist(), self._half, self._radius, cos, sin, strict=True):
            rx, ry = px - cx, py - cy
            qx = abs(rx * c + ry * s) - hx
            qy = abs(-rx * s + ry * c) - hy
            outside = hypot(max(qx, 0.0), max(qy, 0.0))
            out.append(outside + min(max(qx, qy), 0.0) - r - agent_r)
        return np.array(out)
