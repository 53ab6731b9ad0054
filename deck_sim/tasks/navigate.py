"""The navigation task: reach the target among static obstacles and purposeful movers (paper Section II-III).

One control step (``control_period``, 0.5 s by default):
    action (x, y) in [-1, 1]^2, a desired displacement of ``reach * (x, y)`` metres over the next period
    -> tracking controller (``control.tracking``): steer, thrust, brakes (aircraft) or walking velocity
    -> movers' behaviour (``behaviour``): speed and turn rate of every mover, once per control step
    -> physics: the substeps are fused into ``mj_step(nstep)`` calls (composer sees a single substep; its
       per-substep Python would otherwise cost 2-3x the physics, FINDINGS.md), split ``collision_checks``
       times to look for contacts between the agent and obstacles
    -> history of the movers' positions -> predictor -> observation (paper eq. 7-8) and reward (eq. 10-16).

Observation (all relative vectors in the world frame, metres, or in the agent's own with ``episode.frame =
"agent"``; obstacles nearest first):
    ``target`` (2) target minus agent; ``static_obstacles`` (m, 2) static obstacles (on the deck the island is
    the last of m = 15 + 1) minus agent; ``dynamic_obstacles`` (n, 2) movers now minus agent; ``predicted``
    (n, N, 2) predicted mover positions minus agent (absent when N = 0; minus each mover's position now with
    ``episode.predicted_frame = "mover"``); ``position`` (2) the agent's own
    position (where the deck edges are); ``velocity`` (2) m/s; ``heading`` (2) cos and sin of yaw. Options of
    the scene's ``[episode]`` add the obstacles' shapes (``obstacle_shape``), the movers' sizes (``mover_size``),
    the target and edges clipped to a few steps' reach (``near_steps``: ``target_near``, ``edge_near``; with
    ``near_obstacles`` also every obstacle's nearest point clipped to it, ``static_near``, ``dynamic_near``) and the
    next points of the shortest way round the static obstacles (``route_steps``: ``route``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from dm_control import composer, mjcf
from dm_control.composer.observation import observable
from dm_env import specs

from deck_sim.behaviour import BehaviourParams, MoverBehaviour
from deck_sim.control.prediction import (
    ConstantVelocity,
    Predictor,
    constant_velocity_rollout,
    least_squares_velocity,
    make_predictor,
)
from deck_sim.control.tracking import AircraftLimits, speed_and_yaw_rate, track_displacement, track_velocity
from deck_sim.entities import Aircraft, Pedestrian, StaticProp, Tractor, make_arena
from deck_sim.geometry import (
    Footprints,
    NoPathError,
    VisibilityGraph,
    clip_length,
    end_circles,
    points_along,
    world_to_agent,
)
from deck_sim.scenes import ROUTE_MARGIN, SceneSpec
from deck_sim.tasks import rewards
from deck_sim.types import ObstacleKind, ObstacleTracks, PlannerView, Prediction

log = logging.getLogger(__name__)

_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
)


_NO_SENSORS = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
"""The disable flag that skips sensor computation on the fused substeps between contact checks."""


class LayoutError(RuntimeError):
    """The episode's layout could not be sampled (rejection sampling ran out of attempts)."""


_TURNED_KEYS = (
    "target",
    "static_obstacles",
    "dynamic_obstacles",
    "predicted",
    "static_nearest",
    "dynamic_nearest",
    "dynamic_heading",
    "target_near",
    "static_near",
    "dynamic_near",
    "route",
    "velocity",
)
"""Observation keys holding world vectors (..., 2) that ``episode.frame = "agent"`` turns into the agent's axes."""


class InvalidActionError(ValueError):
    """An action is not a finite pair in [-1, 1]."""


@dataclass
class Layout:
    """Where everything starts in one episode (planar, metres and radians)."""

    agent_xy: np.ndarray
    agent_yaw: float
    target_xy: np.ndarray
    static_xy: np.ndarray  # (m, 2)
    static_yaw: np.ndarray  # (m,)
    mover_xy: np.ndarray  # (n, 2)
    mover_spot: np.ndarray  # (n,) spot index or -1
    target_site: str = ""
    static_sites: list[str] = field(default_factory=list)


class Navigate(composer.Task):
    """Reach a target among static obstacles and movers, on the deck or in the square.

    Args:
        spec: the scene (``deck_sim.scenes.load_scene``).
        predictor: overrides the predictor named by ``spec.episode.predictor``.
    """

    def __init__(self, spec: SceneSpec, predictor: Predictor | None = None) -> None:
        self.spec = spec
        ep = spec.episode
        self._arena = make_arena(spec.arena)
        arena = self._arena
        for name in (*spec.agent.start_sites, *spec.agent.target_sites, *spec.movers.spots):
            arena.site(name)  # raises naming the site if the arena lacks it

        # the agent
        if spec.agent.vehicle == "aircraft":
            self._agent: Aircraft | Pedestrian = Aircraft("agent")
            arena.add_free_entity(self._agent)
            # the nose and tail stick out of the wing-span disc: the scripted planner may check them too
            self._agent_circles = end_circles(self._agent.parts, spec.agent.radius)
        else:
            self._agent = Pedestrian("agent", rgba=(0.85, 0.15, 0.1, 1.0))
            arena.attach(self._agent)
            self._agent_circles = np.zeros((0, 3))
        self._aircraft_limits: AircraftLimits | None = None

        # static obstacles, joint-less
        self._statics: list[StaticProp] = []
        for i in range(spec.static.slotted):
            self._statics.append(StaticProp(spec.static.slotted_kind, name=f"{spec.static.slotted_kind}_{i:02d}"))
        for i in range(spec.static.scattered):
            self._statics.append(StaticProp("crowd_group", name=f"crowd_group_{i:02d}"))
        for prop in self._statics:
            arena.attach(prop)

        # movers
        self._movers: list[Tractor | Aircraft | Pedestrian] = []
        for i in range(spec.movers.tractors):
            self._movers.append(Tractor(f"tractor_{i}"))
        for i in range(spec.movers.aircraft):
            self._movers.append(Aircraft(f"taxiing_{i}"))
        for i in range(spec.movers.pedestrians):
            self._movers.append(Pedestrian(f"pedestrian_{i:02d}"))
        for mover in self._movers:
            if isinstance(mover, Pedestrian):
                arena.attach(mover)
            else:
                arena.add_free_entity(mover)

        # target marker and cameras
        self._target_body = arena.mjcf_model.worldbody.add("body", name="target")
        self._target_body.add(
            "geom",
            name="target_visual",
            type="cylinder",
            size=[spec.agent.goal_radius, 0.03],
            rgba=[0.1, 0.9, 0.2, 0.5],
            contype=0,
            conaffinity=0,
            group=2,
        )
        lo, hi = arena.bounds
        centre, extent = (lo + hi) / 2.0, (hi - lo) * 1.06
        height = 1.5 * float(extent[0])
        # straight down, image x = world x; the vertical field of view frames the surface's y extent, so an
        # image of aspect extent_x / extent_y (``top_view_size``) shows the whole surface
        arena.mjcf_model.worldbody.add(
            "camera",
            name="top",
            pos=[centre[0], centre[1], height],
            xyaxes=[1, 0, 0, 0, 1, 0],
            fovy=float(np.degrees(2 * np.arctan(extent[1] / 2 / height))),
        )
        self.top_view_aspect = float(extent[0] / extent[1])
        follow_height = 60.0 if spec.agent.vehicle == "aircraft" else 12.0
        arena.mjcf_model.worldbody.add(
            "camera",
            name="follow",
            mode="targetbody",
            target=self._agent.root_body,
            pos=[lo[0], centre[1], follow_height],
        )
        self._agent.mjcf_model.worldbody.add(
            "camera", name="chase", mode="trackcom", pos=[0, 0, follow_height], xyaxes=[1, 0, 0, 0, 1, 0]
        )
        # how many contacts the agent's own body has (its wheels are child bodies, so the deck does not count):
        # MuJoCo counts them in every step, so the contact list is read only when there is something to name
        self._contact_sensor = self._agent.mjcf_model.sensor.add(
            "contact", name="obstacle_contacts", body1=self._agent.root_body, data="found", reduce="mindist"
        )

        # composer sees one substep per control step; after_compile restores the real timestep
        self._n_sub = int(round(ep.control_period / ep.physics_timestep))
        self.set_timesteps(control_timestep=ep.control_period, physics_timestep=ep.control_period)

        self._predictor = predictor or make_predictor(ep.predictor, ep.horizon, ep.control_period)
        self._horizon = int(self._predictor.horizon)
        self._spot_xy = np.array([arena.site(s).xy for s in spec.movers.spots]).reshape(-1, 2)
        self._kinds = np.array(
            [ObstacleKind.PEDESTRIAN if isinstance(m, Pedestrian) else ObstacleKind.WHEELED for m in self._movers],
            dtype=int,
        )
        self._no_fallback = np.zeros(len(self._kinds), dtype=bool)  # (shared by the fast path's predictions)
        self._mover_half = np.array([m.footprint[1] for m in self._movers]).reshape(-1, 2)
        self._mover_radius_fp = np.array([m.footprint[2] for m in self._movers])
        self._mover_size = self._mover_half + self._mover_radius_fp[:, None]
        self._predicted_from_agent = spec.episode.predicted_frame == "agent"
        self._near = spec.episode.near_steps * spec.agent.reach  # metres of the near field; 0: not observed
        self._agent_frame = spec.episode.frame == "agent"  # observation and action in the agent's axes
        self._route_steps = spec.episode.route_steps  # points of the observed route; 0: not observed
        self._route_graph: VisibilityGraph | None = None  # the statics' graph for a disc of the agent (per episode)
        self._mover_spawn_radius = np.hypot(self._mover_half[:, 0], self._mover_half[:, 1]) + self._mover_radius_fp
        # disc radius of each mover for routes and yielding: half the width for vehicles that drive forward
        self._mover_disc = np.array(
            [m.footprint[2] if isinstance(m, Pedestrian) else float(m.footprint[1][1]) for m in self._movers]
        )
        self._behaviour = MoverBehaviour(
            spots=self._spot_xy,
            holonomic=self._kinds == ObstacleKind.PEDESTRIAN,
            radii=self._mover_disc,
            fronts=np.where(self._kinds == ObstacleKind.PEDESTRIAN, self._mover_disc, self._mover_half[:, 0]),
            agent_radius=spec.agent.radius,
            agent_parts=self._agent.parts,
            params=BehaviourParams(
                speed_range=spec.movers.speed_range,
                dwell_range=spec.movers.dwell_range,
                accel=spec.movers.accel,
                decel=spec.movers.decel,
                turn_rate=spec.movers.turn_rate,
                yield_distance=spec.movers.yield_distance,
                yield_to_agent=spec.movers.yield_to_agent,
                agent_yield_distance=spec.movers.agent_yield_distance,
                agent_yield_braking=spec.movers.agent_yield_braking,
                arrive_tolerance=1.0 if spec.arena == "deck" else 0.5,
                waypoint_tolerance=2.5 if spec.arena == "deck" else 0.8,
            ),
        )
        self._obs: dict[str, np.ndarray] = {}
        self.last_info: dict[str, Any] = {}
        self._build_observables()

    # -- composer plumbing ---------------------------------------------------------------------------------
    @property
    def root_entity(self) -> composer.Entity:
        return self._arena

    @property
    def arena(self):  # noqa: ANN201 - the arena class is private to entities
        """The arena entity (its ``sites`` and ``bounds``)."""
        return self._arena

    @property
    def agent(self) -> Aircraft | Pedestrian:
        """The agent's entity."""
        return self._agent

    @property
    def movers(self) -> list[Tractor | Aircraft | Pedestrian]:
        """The movers' entities."""
        return self._movers

    @property
    def statics(self) -> list[StaticProp]:
        """The static obstacles' entities."""
        return self._statics

    @property
    def predictor(self) -> Predictor:
        """The predictor filling the observation's predicted part."""
        return self._predictor

    @property
    def obstacle_names(self) -> list[str]:
        """Names of the obstacles: the static ones (the arena's own, e.g. the island, last), then the movers.

        The order of ``planner_view().statics`` followed by ``planner_view().movers``; a collision partner in
        ``last_info["collision"]`` is one of these names. Available once the model is compiled.
        """
        return list(self._obstacle_names)

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step."""
        return self._n_sub

    def _build_observables(self) -> None:
        m = len(self._statics) + len(self._arena.fixed_obstacle_geoms)
        n = len(self._movers)
        shapes = {"target": (2,), "static_obstacles": (m, 2), "dynamic_obstacles": (n, 2)}
        if self._horizon > 0:
            shapes["predicted"] = (n, self._horizon, 2)
        if self.spec.episode.obstacle_shape:
            shapes.update({"static_nearest": (m, 2), "dynamic_nearest": (n, 2), "dynamic_heading": (n, 2)})
        if self.spec.episode.mover_size:
            shapes["dynamic_size"] = (n, 2)
        if self._near > 0:
            shapes.update({"target_near": (2,), "edge_near": (4,)})
            if self.spec.episode.near_obstacles:
                shapes.update({"static_near": (m, 2), "dynamic_near": (n, 2)})
        if self._route_steps > 0:
            shapes["route"] = (self._route_steps, 2)
        shapes.update({"position": (2,), "velocity": (2,), "heading": (2,)})
        self._obs_shapes = shapes
        self._obs = {k: np.zeros(v) for k, v in shapes.items()}  # until the first episode starts
        self._task_observables = {}
        for key in shapes:
            obs = observable.Generic(lambda physics, key=key: self._obs[key])
            obs.enabled = True
            self._task_observables[key] = obs

    @property
    def task_observables(self) -> dict[str, observable.Observable]:
        return self._task_observables

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        """Shape of every observation, in order."""
        return dict(self._obs_shapes)

    def action_spec(self, physics: mjcf.Physics) -> specs.BoundedArray:
        """(x, y) in [-1, 1]^2: desired displacement over the next period as a fraction of the reach."""
        return specs.BoundedArray((2,), np.float64, -1.0, 1.0, name="dx\tdy")

    def after_compile(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Restore the real physics timestep and cache the indices the hot path uses."""
        m = physics.model
        m.opt.timestep = self.spec.episode.physics_timestep
        self._m, self._d = m.ptr, physics.data.ptr
        vehicles = [self._agent, *self._movers]
        self._body_ids = np.array([physics.bind(v.root_body).element_id for v in vehicles])
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
        self._ctrl_agent = np.array(physics.bind(list(self._agent.actuators)).element_id)
        groups: dict[str, list[int]] = {"tractor": [], "aircraft": [], "pedestrian": []}
        ctrl: dict[str, list[np.ndarray]] = {"tractor": [], "aircraft": [], "pedestrian": []}
        for i, mover in enumerate(self._movers):
            kind = (
                "pedestrian"
                if isinstance(mover, Pedestrian)
                else "aircraft"
                if isinstance(mover, Aircraft)
                else "tractor"
            )
            groups[kind].append(i)
            ctrl[kind].append(np.array(physics.bind(list(mover.actuators)).element_id))
        self._mover_groups = {k: np.array(v, dtype=int) for k, v in groups.items()}
        self._mover_ctrl = {k: (np.array(v, dtype=int) if v else np.zeros((0, 2), dtype=int)) for k, v in ctrl.items()}
        # the hot path writes every mover's controls in one assignment: tractors, aircraft, pedestrians
        self._mover_rows = dict(groups)
        self._mover_ctrl_flat = np.concatenate([self._mover_ctrl[k].ravel() for k in groups]).astype(int)
        # controller constants come from the compiled model, not from copies of the XML's numbers
        if isinstance(self._agent, Aircraft):
            self._aircraft_limits = AircraftLimits(**self._agent.physical_limits(physics))
        taxiing = [mv for mv in self._movers if isinstance(mv, Aircraft)]
        if taxiing:
            self._mover_limits = AircraftLimits(
                **taxiing[0].physical_limits(physics), max_speed=self.spec.movers.speed_range[1]
            )
        tractors = [mv for mv in self._movers if isinstance(mv, Tractor)]
        if tractors:
            self._tractor_track, self._tractor_wheel_radius = tractors[0].drive_geometry(physics)
        # contact bookkeeping: which geoms are the agent's, which obstacle owns every other geom
        self._obstacle_names = [p.mjcf_model.model for p in self._statics]
        self._obstacle_names += [g.name for g in self._arena.fixed_obstacle_geoms]
        self._obstacle_names += [mv.mjcf_model.model for mv in self._movers]
        owner = np.full(m.ngeom, -1, dtype=int)
        k = 0
        for p in self._statics:
            owner[[physics.bind(g).element_id for g in p.mjcf_model.find_all("geom")]] = k
            k += 1
        for g in self._arena.fixed_obstacle_geoms:
            owner[physics.bind(g).element_id] = k
            k += 1
        for mv in self._movers:
            owner[[physics.bind(g).element_id for g in mv.mjcf_model.find_all("geom")]] = k
            k += 1
        self._geom_owner = owner
        self._agent_geom = np.zeros(m.ngeom, dtype=bool)
        self._agent_geom[[physics.bind(g).element_id for g in self._agent.mjcf_model.find_all("geom")]] = True
        self._target_id = physics.bind(self._target_body).element_id
        self._contact_adr = int(physics.bind(self._contact_sensor).adr)
        self._warning_ids = np.array([int(w) for w in _DIVERGENCE_WARNINGS])
        # the fused substeps (all but composer's last one), split for contact checks
        n_fused = self._n_sub - 1
        edges = np.linspace(0, n_fused, self.spec.episode.collision_checks + 1).round().astype(int)
        self._chunks = [int(c) for c in np.diff(edges) if c > 0]
        self._is_ped = np.array([isinstance(v, Pedestrian) for v in vehicles])
        self._any_ped = bool(self._is_ped.any())

    # -- episode set-up --------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> Layout:
        """Draw a non-overlapping layout for one episode.

        Raises:
            LayoutError: naming what could not be placed and why.
        """
        spec, arena = self.spec, self._arena
        a = spec.agent
        lo, hi = arena.bounds
        fixed = arena.fixed_obstacles()

        start = arena.site(a.start_sites[rng.integers(len(a.start_sites))])
        agent_xy = start.xy + rng.uniform(-a.start_jitter, a.start_jitter, 2)
        agent_yaw = float(start.yaw + rng.uniform(-a.yaw_jitter, a.yaw_jitter))
        targets = [arena.site(s) for s in a.target_sites]
        for _ in range(100):
            site = targets[rng.integers(len(targets))]
            target_xy = site.xy + rng.uniform(-a.target_jitter, a.target_jitter, 2)
            if a.min_target_distance <= np.linalg.norm(target_xy - agent_xy) <= a.max_target_distance:
                break
        else:
            raise LayoutError(
                f"{spec.name}: no target among {list(a.target_sites)} lies "
                f"{a.min_target_distance}-{a.max_target_distance} m from the start {start.name}"
            )

        # slotted statics: slots clear of the start and the target
        slots = arena.sites_with_prefix(spec.static.slot_prefix)
        kind_fp = self._statics[0].footprint if spec.static.slotted else None  # slotted props come first
        free = []
        for s in slots if kind_fp is not None else []:
            fp = Footprints(np.array([[s.x, s.y]]), kind_fp[1][None], np.array([s.yaw]), np.array([kind_fp[2]]))
            d_start = fp.distance(agent_xy)[0, 0]
            d_target = fp.distance(target_xy)[0, 0]
            if d_start > a.radius + 2.0 and d_target > a.radius + a.goal_radius:
                free.append(s)
        if len(free) < spec.static.slotted:
            raise LayoutError(
                f"{spec.name}: only {len(free)} of {len(slots)} '{spec.static.slot_prefix}*' slots are "
                f"clear of the start and target, {spec.static.slotted} static obstacles need one each"
            )
        chosen = [free[i] for i in sorted(rng.choice(len(free), spec.static.slotted, replace=False))]
        static_xy = [s.xy for s in chosen]
        static_yaw = [s.yaw for s in chosen]
        statics_fp = Footprints.concatenate(
            [
                fixed,
                Footprints(
                    np.array(static_xy).reshape(-1, 2),
                    np.repeat(kind_fp[1][None], len(chosen), 0) if kind_fp else np.zeros((0, 2)),
                    np.array(static_yaw),
                    np.full(len(chosen), kind_fp[2] if kind_fp else 0.0),
                ),
            ]
        )

        # scattered standing groups (square): uniform on free ground
        group_r = 1.2
        keep_clear = [(agent_xy, a.radius + 1.0), (target_xy, a.goal_radius + 1.0)]
        keep_clear += [(s, 1.5) for s in self._spot_xy]
        scattered: list[np.ndarray] = []
        for i in range(spec.static.scattered):
            for _ in range(2000):
                p = rng.uniform(lo + group_r + 1.0, hi - group_r - 1.0)
                c = spec.static.scatter_clearance + group_r
                if (
                    statics_fp.distance(p).min(initial=np.inf) > c
                    and all(np.linalg.norm(p - q) > r + c for q, r in keep_clear)
                    and all(np.linalg.norm(p - q) > 2 * group_r + c for q in scattered)
                ):
                    scattered.append(p)
                    break
            else:
                raise LayoutError(
                    f"{spec.name}: could not place standing group {i + 1} of {spec.static.scattered} "
                    f"with {spec.static.scatter_clearance} m clearance after 2000 tries"
                )
        static_xy += scattered
        static_yaw += [0.0] * len(scattered)
        all_fp = Footprints.concatenate(
            [
                statics_fp,
                Footprints(
                    np.array(scattered).reshape(-1, 2),
                    np.zeros((len(scattered), 2)),
                    np.zeros(len(scattered)),
                    np.full(len(scattered), group_r),
                ),
            ]
        )

        # movers: at distinct spots, near the agent, or anywhere free
        mv = spec.movers
        n = len(self._movers)
        mover_xy = np.zeros((n, 2))
        mover_spot = np.full(n, -1)
        order = rng.permutation(n)
        near = set(order[: mv.spawn_near_agent].tolist())
        anywhere = set(order[mv.spawn_near_agent : mv.spawn_near_agent + mv.spawn_random].tolist())
        spot_order = list(rng.permutation(len(self._spot_xy)))
        placed: list[tuple[np.ndarray, float]] = [(agent_xy, a.radius)]
        for i in range(n):
            r = self._mover_spawn_radius[i]  # circumscribed: safe whatever the initial heading

            def free(p: np.ndarray, r: float = r) -> bool:
                return bool(
                    np.all(p > lo + r)
                    and np.all(p < hi - r)
                    and all_fp.distance(p).min(initial=np.inf) > r + 0.5
                    and np.linalg.norm(p - target_xy) > a.goal_radius + r + 2.0
                    and all(np.linalg.norm(p - q) > r + rq + 2.0 for q, rq in placed)
                )

            ok = False
            if i not in near and i not in anywhere:
                while spot_order:
                    s = spot_order.pop()
                    if free(self._spot_xy[s]):
                        mover_xy[i], mover_spot[i], ok = self._spot_xy[s], s, True
                        break
                if not ok:  # no usable spot left (too many movers, or too tight for this one): free ground
                    anywhere.add(i)
            for _ in range(2000 if not ok else 0):
                if i in near:
                    ang = rng.uniform(-np.pi, np.pi)
                    rad = rng.uniform(a.radius + r + 3.0, max(mv.near_radius, a.radius + r + 4.0))
                    p = agent_xy + rad * np.array([np.cos(ang), np.sin(ang)])
                else:
                    p = rng.uniform(lo + r + 1.0, hi - r - 1.0)
                if free(p):
                    mover_xy[i], ok = p, True
                    break
            if not ok:
                raise LayoutError(
                    f"{spec.name}: could not place mover {self._movers[i].mjcf_model.model} on free "
                    "ground after 2000 tries"
                )
            placed.append((mover_xy[i], r))

        return Layout(
            agent_xy=agent_xy,
            agent_yaw=agent_yaw,
            target_xy=target_xy,
            static_xy=np.array(static_xy).reshape(-1, 2),
            static_yaw=np.array(static_yaw),
            mover_xy=mover_xy,
            mover_spot=mover_spot,
            target_site=site.name,
            static_sites=[s.name for s in chosen],
        )

    def initialize_episode(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Sample a layout, place everything, plan the movers' first trips and compute the first observation."""
        rng = np.random.default_rng(random_state.randint(2**32 - 1))
        layout = self.sample_layout(rng)
        self.layout = layout
        spec = self.spec
        if isinstance(self._agent, Aircraft):
            self._agent.set_pose(physics, np.array([*layout.agent_xy, 1.8]), _yaw_quat(layout.agent_yaw))
            self._agent.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
        else:
            # a pedestrian's slide joints live in its attachment frame: keep that frame unrotated (world axes)
            self._agent.set_pose(physics, np.array([*layout.agent_xy, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
            physics.bind(list(self._agent.joints)).qpos = 0.0
            physics.bind(list(self._agent.joints)).qvel = 0.0
        for prop, xy, yaw in zip(self._statics, layout.static_xy, layout.static_yaw, strict=True):
            prop.set_pose(physics, np.array([*xy, 0.0]), _yaw_quat(yaw))
        physics.bind(self._target_body).pos = np.array([*layout.target_xy, 0.0])

        # fixed obstacle footprints this episode (statics + the arena's own)
        self._static_fp = Footprints.concatenate(
            [
                Footprints(
                    layout.static_xy
                    + _rotate(np.array([p.footprint[0] for p in self._statics]).reshape(-1, 2), layout.static_yaw),
                    np.array([p.footprint[1] for p in self._statics]).reshape(-1, 2),
                    layout.static_yaw,
                    np.array([p.footprint[2] for p in self._statics]),
                ),
                self._arena.fixed_obstacles(),
            ]
        )
        self._static_centres = self._static_fp.centers
        if self._route_steps > 0:
            self._route_graph = VisibilityGraph(
                self._static_fp, self.spec.agent.radius + ROUTE_MARGIN, self._arena.bounds
            )
        self._all_fp = Footprints.concatenate(
            [  # statics, then movers (rows refreshed every step)
                self._static_fp,
                Footprints(
                    layout.mover_xy.copy(),
                    self._mover_half.copy(),
                    np.zeros(len(self._movers)),
                    self._mover_radius_fp.copy(),
                ),
            ]
        )
        self._all_half_l, self._all_radius_l = self._all_fp.half.tolist(), self._all_fp.radius.tolist()
        # route graphs, one per distinct mover clearance
        graphs: dict[float, VisibilityGraph] = {}
        mover_graphs = []
        for r in self._mover_disc:
            key = round(float(r) + spec.movers.clearance, 3)
            if key not in graphs:
                graphs[key] = VisibilityGraph(self._static_fp, key, self._arena.bounds)
            mover_graphs.append(graphs[key])
        self._behaviour.reset(mover_graphs, layout.mover_xy, layout.mover_spot, rng)
        aim = self._behaviour.aim - layout.mover_xy
        mover_yaw = np.arctan2(aim[:, 1], aim[:, 0])
        for i, mover in enumerate(self._movers):
            if isinstance(mover, Pedestrian):
                mover.set_pose(physics, np.array([*layout.mover_xy[i], 0.0]))
                physics.bind(list(mover.joints)).qpos = 0.0
                physics.bind(list(mover.joints)).qvel = 0.0
            else:
                z = 1.8 if isinstance(mover, Aircraft) else 0.0
                mover.set_pose(physics, np.array([*layout.mover_xy[i], z]), _yaw_quat(mover_yaw[i]))
                mover.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
        physics.data.ctrl[:] = 0.0
        physics.forward()

        # episode bookkeeping
        self._state = self._read_state()
        agent_xy = self._state["xy"][0]
        self._history = np.repeat(self._state["xy"][1:, None, :], spec.episode.history, axis=1)
        self._predictor.reset(self._spot_xy, self._kinds)
        self._prediction = self._predict(physics)
        self._dist_target = float(np.linalg.norm(layout.target_xy - agent_xy))
        self._clearances = self._obstacle_clearances(self._state)
        self._collided_with: str | None = None
        self._reached = self._off_surface = self._diverged = False
        self._warnings_before = sum(self._d.warning.number[self._warning_ids].tolist())
        self._terminal = False
        self._reward = rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0)
        self._fallbacks_total = 0
        self._rescued = 0
        self._update_observation()
        self._update_info(physics)

    # -- one control step ----------------------------------------------------------------------------------
    def before_step(self, physics: mjcf.Physics, action: np.ndarray, random_state: np.random.RandomState) -> None:
        """Check the action, set every actuator, and run all physics substeps but composer's last one."""
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (2,):
            raise InvalidActionError(f"action must have shape (2,), got {action.shape}")
        a0, a1 = action.tolist()  # (plain floats: numpy's calls on two numbers cost more than the checks)
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise InvalidActionError(f"action must be finite, got {action.tolist()}")
        if abs(a0) > 1.0 + 1e-6 or abs(a1) > 1.0 + 1e-6:
            raise InvalidActionError(f"action must lie in [-1, 1]^2, got {action.tolist()}")
        spec, d, st = self.spec, self._d, self._state
        period = spec.episode.control_period
        self._last_action = action
        if self._agent_frame:  # ahead and to the left -> the world's axes (``agent_to_world`` on two floats)
            c, s = math.cos(float(st["yaw"][0])), math.sin(float(st["yaw"][0]))
            a0, a1 = c * a0 - s * a1, s * a0 + c * a1
            action = np.array([a0, a1])
        if isinstance(self._agent, Aircraft):
            reach = spec.agent.reach
            cmd = track_displacement(
                a0 * reach,
                a1 * reach,
                float(st["yaw"][0]),
                float(st["forward_speed"][0]),
                period,
                self._aircraft_limits,
            )
            d.ctrl[self._ctrl_agent] = (cmd.steer, cmd.thrust, cmd.brake, cmd.brake)
        else:
            displacement = action * spec.agent.reach
            d.ctrl[self._ctrl_agent] = track_velocity(displacement[None], period, spec.agent.reach / period)[0]
        self._command_movers(self._d.time, st)

        # fused substeps, split for collision checks; composer runs the final one
        warnings = d.warning.number
        self._warnings_before = sum(warnings[self._warning_ids].tolist())  # compared in ``after_step``
        self._collided_with = None
        # Sensors are read only at the end of a chunk (the contact sensor) and of the control step, and nothing in
        # the dynamics depends on them: skipping them on the steps in between (the accelerometer alone makes MuJoCo
        # run mj_rnePostConstraint every step) leaves the trajectory and every value read bit-identical.
        opt = self._m.opt
        flags = opt.disableflags
        for c in self._chunks:
            if c > 1:
                opt.disableflags = flags | _NO_SENSORS
                try:
                    mujoco.mj_step(self._m, d, nstep=c - 1)
                finally:
                    opt.disableflags = flags
            mujoco.mj_step(self._m, d, nstep=1)
            self._check_contacts()

    def _command_movers(self, t: float, st: dict[str, np.ndarray]) -> None:
        if not self._movers:
            return
        cmd = self._behaviour.command(
            t,
            self.spec.episode.control_period,
            st["xy"][1:],
            st["yaw"][1:],
            st["forward_speed"][1:],
            st["xy"][0],
            float(st["yaw"][0]),
        )
        speed, yaw_rate = cmd.speed.tolist(), cmd.yaw_rate.tolist()
        rows = self._mover_rows
        ctrl: list[float] = []  # in the order of ``_mover_ctrl_flat``
        if rows["tractor"]:
            half_track, radius = self._tractor_track / 2, self._tractor_wheel_radius
            for i in rows["tractor"]:
                v, w = speed[i], yaw_rate[i]
                ctrl += ((v - w * half_track) / radius, (v + w * half_track) / radius)
        if rows["aircraft"]:
            speeds = st["forward_speed"].tolist()
            for i in rows["aircraft"]:
                ac = speed_and_yaw_rate(speed[i], yaw_rate[i], speeds[1 + i], self._mover_limits)
                ctrl += (ac.steer, ac.thrust, ac.brake, ac.brake)
        if rows["pedestrian"]:
            velocity = cmd.velocity.tolist()
            for i in rows["pedestrian"]:
                ctrl += velocity[i]
        self._d.ctrl[self._mover_ctrl_flat] = ctrl

    def _check_contacts(self) -> None:
        """Record the first obstacle the agent touches (contacts between bodies only; wheels touch the deck)."""
        d = self._d
        if self._collided_with is not None or d.sensordata[self._contact_adr] == 0.0:
            return
        geom = d.contact.geom[: d.ncon]
        a0, a1 = self._agent_geom[geom[:, 0]], self._agent_geom[geom[:, 1]]
        other = np.where(a0, geom[:, 1], geom[:, 0])[a0 ^ a1]
        owners = self._geom_owner[other]
        owners = owners[owners >= 0]
        if len(owners):
            self._collided_with = self._obstacle_names[int(owners[0])]

    def after_step(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Read the new state, update histories, prediction, reward, termination and observation."""
        self._check_contacts()
        d = self._d
        # divergence over the whole control step, composer's substep included (MuJoCo warns and resets the state)
        warnings = sum(d.warning.number[self._warning_ids].tolist())
        self._diverged = warnings > self._warnings_before or not np.isfinite(d.qpos).all()
        spec = self.spec
        st = self._read_state()
        on_surface = self._arena.on_surface(st["xy"])  # the agent, then every mover
        lost = ~on_surface[1:] | (d.xpos[self._body_ids[1:], 2] < -1.0)
        if lost.any():  # rare: a crash pushed a mover off the surface
            self._rescue_movers(physics, np.flatnonzero(lost), st)
            st = self._read_state()
        self._state = st
        agent_xy = st["xy"][0]
        self._history[:, :-1] = self._history[:, 1:]  # shift in place, newest last
        self._history[:, -1] = st["xy"][1:]
        self._prediction = self._predict(physics)

        to_target = self.layout.target_xy - agent_xy
        dist = math.sqrt(to_target.dot(to_target))  # as np.linalg.norm computes it
        clear = self._obstacle_clearances(st)
        r = spec.reward
        self._reached = dist <= spec.agent.goal_radius and self._collided_with is None
        self._off_surface = not bool(on_surface[0])
        failed = self._collided_with is not None or self._off_surface
        if self._diverged:
            self._reward = rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            r1 = rewards.attraction(self._dist_target, dist, r.attraction_min, r.attraction_max, r.progress_deadband)
            r2 = rewards.repulsion(
                self._clearances,
                clear,
                r.influence_radius,
                r.repulsion_min,
                r.repulsion_max,
                r.progress_deadband,
            )
            self._reward = rewards.total_reward(
                r1,
                r2,
                failed,
                self._reached,
                r.collision,
                r.goal,
                (r.w_attraction, r.w_repulsion, r.w_collision, r.w_goal),
            )
        self._dist_target, self._clearances = dist, clear
        self._terminal = self._reached or failed or self._diverged
        if self._diverged:
            log.warning("%s: physics diverged at t=%.2f s; episode ended", spec.name, physics.data.time)
        self._update_observation()
        self._update_info(physics)

    def _rescue_movers(self, physics: mjcf.Physics, lost: np.ndarray, st: dict[str, np.ndarray]) -> None:
        """Put movers that left the surface (pushed off in a crash) back at rest on their next spot.

        A safety net, not behaviour: it is logged and counted in ``last_info["movers_rescued"]``.
        """
        for i in lost:
            mover = self._movers[i]
            xy = self._spot_xy[self._behaviour.spot[i]]
            log.warning(
                "%s: mover %s left the surface at %s; placed back at its next spot %s",
                self.spec.name,
                mover.mjcf_model.model,
                st["xy"][1 + i].round(1),
                xy.round(1),
            )
            if isinstance(mover, Pedestrian):
                physics.bind(list(mover.joints)).qpos = (
                    xy - physics.bind(mjcf.get_attachment_frame(mover.mjcf_model)).pos[:2]
                )
                physics.bind(list(mover.joints)).qvel = 0.0
            else:
                z = 1.8 if isinstance(mover, Aircraft) else 0.0
                mover.set_pose(physics, np.array([*xy, z]), _yaw_quat(0.0))
                mover.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
            self._behaviour.mode[i] = 1  # dwell, then leave as usual
            self._behaviour.dwell_until[i] = physics.data.time + self.spec.movers.dwell_range[0]
            self._rescued += 1
        mujoco.mj_forward(self._m, self._d)

    def get_reward(self, physics: mjcf.Physics) -> float:
        """Eq. 16 for the last step."""
        return self._reward.total

    def should_terminate_episode(self, physics: mjcf.Physics) -> bool:
        """Goal, collision, leaving the surface or divergence (the time limit is the environment's)."""
        return self._terminal

    def get_discount(self, physics: mjcf.Physics) -> float:
        """0 on termination, 1 otherwise (a time-limit truncation keeps discount 1)."""
        return 0.0 if self._terminal else 1.0

    # -- state, prediction, observation -------------------------------------------------------------------
    def _read_state(self) -> dict[str, np.ndarray]:
        """Planar pose and velocity of the agent (row 0) and every mover."""
        d = self._d
        xy = d.xpos[self._body_ids, :2]  # (fancy indexing copies)
        xmat = d.xmat[self._body_ids]
        yaw = np.arctan2(xmat[:, 3], xmat[:, 0])
        vel = d.qvel[self._vel_dofs]
        fwd = vel[:, 0] * np.cos(yaw) + vel[:, 1] * np.sin(yaw)
        # pedestrians have no body heading: their speed is the norm of their velocity
        if self._any_ped:
            fwd[self._is_ped] = np.hypot(vel[self._is_ped, 0], vel[self._is_ped, 1])
        return {"xy": xy, "yaw": yaw, "vel": vel, "forward_speed": fwd}

    def _mover_footprints(self, st: dict[str, np.ndarray]) -> Footprints:
        yaw = st["yaw"][1:]
        return Footprints(st["xy"][1:], self._mover_half, yaw, self._mover_radius_fp)

    def _obstacle_clearances(self, st: dict[str, np.ndarray]) -> np.ndarray:
        """Clearance (k,) from the agent's disc to every static obstacle and mover, metres.

        ``Footprints.distance`` from one point, written out on plain floats (about 25 footprints: numpy's cost
        per call outweighs its work); the cosines and sines still come from numpy. Equal to
        ``self._all_fp.distance(agent)[0] - radius`` to a few ulps (``math.hypot`` rounds differently), NaN where
        it is NaN (the builtin ``max``/``min`` keep a NaN first argument, as numpy's do).
        """
        fp, k = self._all_fp, len(self._static_fp)
        fp.centers[k:] = st["xy"][1:]  # movers' rows are updated in place (hot path)
        fp.yaw[k:] = st["yaw"][1:]
        px, py = st["xy"][0].tolist()
        agent_r, hypot = self.spec.agent.radius, math.hypot
        out = []
        for (cx, cy), (hx, hy), r, c, s in zip(
            fp.centers.tolist(),
            self._all_half_l,
            self._all_radius_l,
            np.cos(fp.yaw).tolist(),
            np.sin(fp.yaw).tolist(),
            strict=True,
        ):
            rx, ry = px - cx, py - cy
            qx = abs(rx * c + ry * s) - hx
            qy = abs(-rx * s + ry * c) - hy
            outside = hypot(max(qx, 0.0), max(qy, 0.0))
            out.append(outside + min(max(qx, qy), 0.0) - r - agent_r)
        return np.array(out)

    def _predict(self, physics: mjcf.Physics) -> Prediction:
        if not self._movers:
            return Prediction(np.zeros((0, self._horizon, 2)), np.zeros(0, dtype=bool))
        if type(self._predictor) is ConstantVelocity:
            # the scenes' default predictor, on the hot path: the task's own history is well formed (MuJoCo resets
            # a diverged state), so ``predict``'s input checks are skipped; the same numbers
            p, dt, hist = self._predictor, self.spec.episode.control_period, self._history
            if not math.isfinite(hist.sum()):  # never expected: let ``predict`` name the problem
                return p.predict(ObstacleTracks(dt=dt, positions=hist, kinds=self._kinds))
            velocity = least_squares_velocity(hist, dt, p.window)
            return Prediction(constant_velocity_rollout(hist[:, -1, :], velocity, dt, p.horizon), self._no_fallback)
        future = self.simulate_future(physics, self._horizon) if self._predictor.needs_future else None
        tracks = ObstacleTracks(
            dt=self.spec.episode.control_period, positions=self._history, kinds=self._kinds, future=future
        )
        prediction = self._predictor.predict(tracks)
        return prediction

    def simulate_future(self, physics: mjcf.Physics, steps: int) -> np.ndarray:
        """The movers' positions over the next ``steps`` control steps, (n, steps, 2), by simulating ahead.

        A copy of the physics state and of the movers' behaviour (its random generator included) is stepped
        forward with the agent braking where it stands; the real episode is untouched. Exact while the movers
        do not react to the agent.
        """
        d_saved = mujoco.MjData(self._m)
        mujoco.mj_copyData(d_saved, self._m, self._d)
        behaviour_saved = self._behaviour.snapshot()
        out = np.zeros((len(self._movers), steps, 2))
        try:
            d = self._d
            if isinstance(self._agent, Aircraft):
                d.ctrl[self._ctrl_agent] = (0.0, 0.0, 1.0, 1.0)
            else:
                d.ctrl[self._ctrl_agent] = 0.0
            st = self._read_state()
            for k in range(steps):
                self._command_movers(d.time, st)
                mujoco.mj_step(self._m, d, nstep=self._n_sub)
                st = self._read_state()
                out[:, k] = st["xy"][1:]
        finally:
            mujoco.mj_copyData(self._d, self._m, d_saved)
            self._behaviour.restore(behaviour_saved)
        return out

    def _update_observation(self) -> None:
        st = self._state
        agent_xy = st["xy"][0]
        statics = self._static_centres - agent_xy
        order_s = np.einsum("ij,ij->i", statics, statics).argsort(kind="stable")
        movers = st["xy"][1:] - agent_xy
        order_m = np.einsum("ij,ij->i", movers, movers).argsort(kind="stable")
        obs = {
            "target": self.layout.target_xy - agent_xy,
            "static_obstacles": statics[order_s],
            "dynamic_obstacles": movers[order_m],
        }
        if self._horizon > 0:
            origin = agent_xy if self._predicted_from_agent else st["xy"][1:][order_m][:, None]
            obs["predicted"] = self._prediction.positions[order_m] - origin
        static_nearest = dynamic_nearest = None
        if self.spec.episode.obstacle_shape or (self._near > 0 and self.spec.episode.near_obstacles):
            static_nearest = self._static_fp.nearest_points(agent_xy)[order_s] - agent_xy
            dynamic_nearest = self._mover_footprints(st).nearest_points(agent_xy)[order_m] - agent_xy
        if self.spec.episode.obstacle_shape:
            obs["static_nearest"] = static_nearest
            obs["dynamic_nearest"] = dynamic_nearest
            yaw = st["yaw"][1:][order_m]
            obs["dynamic_heading"] = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
        if self.spec.episode.mover_size:
            obs["dynamic_size"] = self._mover_size[order_m]
        if self._near > 0:
            near, to_target = self._near, obs["target"]
            length = math.hypot(float(to_target[0]), float(to_target[1]))
            obs["target_near"] = to_target * (near / length) if length > near else to_target.copy()
            lo, hi = self._arena.bounds
            obs["edge_near"] = np.clip(np.concatenate([agent_xy - lo, hi - agent_xy])[[0, 2, 1, 3]], 0.0, near)
            if self.spec.episode.near_obstacles and static_nearest is not None and dynamic_nearest is not None:
                obs["static_near"] = clip_length(static_nearest, near)
                obs["dynamic_near"] = clip_length(dynamic_nearest, near)
        if self._route_steps > 0:
            obs["route"] = self.route_points(agent_xy) - agent_xy
        # ``st`` holds fresh arrays every step that nothing writes to afterwards: rows are handed out as views
        obs["position"] = agent_xy
        obs["velocity"] = st["vel"][0]
        yaw = float(st["yaw"][0])
        obs["heading"] = np.array([math.cos(yaw), math.sin(yaw)])
        if self._agent_frame:  # every relative vector turned by minus the yaw (new arrays: the views stay as they are)
            for key in _TURNED_KEYS:
                if key in obs:
                    obs[key] = world_to_agent(obs[key], yaw)
        self._obs = obs
        self._mover_order = order_m

    def _update_info(self, physics: mjcf.Physics) -> None:
        st = self._state
        self._fallbacks_total += self._prediction.n_fallbacks
        self.last_info = {
            "time": float(self._d.time),
            "position": st["xy"][0].copy(),  # (copies: a caller may write to what it is given)
            "heading": float(st["yaw"][0]),
            "speed": float(st["forward_speed"][0]),
            "distance_to_goal": float(self._dist_target),
            "min_clearance": float(self._clearances.min(initial=np.inf)),
            "reward_terms": self._reward.as_dict(),
            "collision": self._collided_with,
            "reached_goal": bool(self._reached),
            "left_surface": bool(self._off_surface),
            "diverged": bool(self._diverged),
            "predictor": self._predictor.name,
            "predictor_fallbacks": int(self._prediction.n_fallbacks),
            "predictor_fallbacks_total": int(self._fallbacks_total),
            "movers_rescued": int(self._rescued),
            "mover_positions": st["xy"][1:].copy(),
            "mover_yaw": st["yaw"][1:].copy(),
            "prediction": self._prediction.positions.copy(),
        }

    def action_from_world(self, action: np.ndarray) -> np.ndarray:
        """A world-frame action (2,) in this task's action frame (``episode.frame``), clipped to [-1, 1]^2.

        Identity in the world frame; in the agent frame it is turned by minus the agent's current yaw, which is
        exact (no clipping) for actions in the unit disc, as every planner's are. The scripted and classical
        planners plan in the world and go through this (``policies.ScriptedPolicy``)."""
        action = np.asarray(action, dtype=np.float64)
        if not self._agent_frame:
            return action
        return np.clip(world_to_agent(action, float(self._state["yaw"][0])), -1.0, 1.0)

    def route_points(self, agent_xy: np.ndarray) -> np.ndarray:
        """(``route_steps``, 2) world points ``k * agent.reach`` metres (k = 1, 2, ...) along the shortest path
        from ``agent_xy`` to the target around this episode's static obstacles (scene field
        ``episode.route_steps``); the target itself beyond the path's end. Where the graph finds no path (the
        agent boxed in, or inside grown obstacles with no way out), the straight line to the target stands in for
        it, as in the scripted planner."""
        if self._route_graph is None:
            raise RuntimeError("the scene's episode.route_steps is 0: no route is observed")
        target = self.layout.target_xy
        try:
            path = self._route_graph.shortest_path(agent_xy, target)
        except NoPathError:
            path = np.stack([agent_xy, target])
        return points_along(path, self.spec.agent.reach * np.arange(1, self._route_steps + 1))

    def planner_view(self) -> PlannerView:
        """Full knowledge of the current step for the scripted planner."""
        st = self._state
        return PlannerView(
            agent_xy=st["xy"][0].copy(),
            agent_yaw=float(st["yaw"][0]),
            agent_speed=float(st["forward_speed"][0]),
            agent_radius=self.spec.agent.radius,
            target_xy=self.layout.target_xy.copy(),
            goal_radius=self.spec.agent.goal_radius,
            statics=self._static_fp,
            movers=self._mover_footprints(st),
            mover_future=self._prediction.positions.copy(),
            bounds=self._arena.bounds,
            reach=self.spec.agent.reach,
            period=self.spec.episode.control_period,
            agent_circles=self._agent_circles,
            agent_limits=self._aircraft_limits,
        )


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2.0), 0.0, 0.0, np.sin(yaw / 2.0)])


def _rotate(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)
