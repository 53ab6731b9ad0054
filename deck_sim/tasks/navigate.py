"""The navigation task: reach the target among static obstacles and purposeful movers (paper Section II-III).

One control step (``control_period``, 0.5 s by default):
    action (x, y) in [-1, 1]^2, a desired displacement of ``reach * (x, y)`` metres over the next period
    -> tracking controller (``control.tracking``): steer, thrust, brakes (aircraft) or walking velocity
    -> movers' behaviour (``behaviour``): speed and turn rate of every mover, once per control step
    -> physics (``physics_step``): the substeps are fused into ``mj_step(nstep)`` calls, split
       ``collision_checks`` times to look for contacts between the agent and obstacles
    -> history of the movers' positions -> predictor -> observation (``observation``, paper eq. 7-8) and reward
       (eq. 10-16).

Episode layouts are drawn by ``layout.sample_layout``; the movers' controls are written by ``movers.MoverDriver``.
"""

from __future__ import annotations

import logging
import math
import sys
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
from deck_sim.control.tracking import AircraftLimits, track_displacement, track_velocity
from deck_sim.entities import Aircraft, Pedestrian, StaticProp, Tractor, make_arena
from deck_sim.geometry import (
    Footprints,
    NoPathError,
    VisibilityGraph,
    agent_to_world,
    end_circles,
    points_along,
    world_to_agent,
)
from deck_sim.scenes import ROUTE_MARGIN, SceneSpec
from deck_sim.tasks import rewards
from deck_sim.tasks.actions import InvalidActionError, checked_action
from deck_sim.tasks.layout import Layout, LayoutError, sample_layout, static_footprints, yaw_quat
from deck_sim.tasks.movers import MoverDriver
from deck_sim.tasks.observation import TURNED_KEYS, ObservationConfig, build_observation, observation_shapes
from deck_sim.tasks.physics_step import Clearances, FusedStepper, as_slice
from deck_sim.types import ObstacleKind, ObstacleTracks, PlannerView, Prediction

__all__ = ["InvalidActionError", "Layout", "LayoutError", "Navigate"]

log = logging.getLogger(__name__)

_AGENT_COLOURS = [(0.1, 0.9, 0.2), (0.2, 0.5, 1.0), (1.0, 0.6, 0.1), (0.9, 0.2, 0.9)]
"""RGB of the target markers of a multi-agent scene's aircraft, in turn."""


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

        # the agent (the first of ``agents.count`` aircraft in a multi-agent scene: ``aircraft_0`` ...)
        self._n_agents = k = spec.agents.count
        if spec.agent.vehicle == "aircraft":
            names = ["agent"] if k == 1 else [f"aircraft_{i}" for i in range(k)]
            self._agents: list[Aircraft | Pedestrian] = [Aircraft(name) for name in names]
            self._agent: Aircraft | Pedestrian = self._agents[0]
            for agent in self._agents:
                arena.add_free_entity(agent)
            # the nose and tail stick out of the wing-span disc: the scripted planner may check them too
            self._agent_circles = end_circles(self._agent.parts, spec.agent.radius)
        else:
            self._agent = Pedestrian("agent", rgba=(0.85, 0.15, 0.1, 1.0))
            self._agents = [self._agent]
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

        # target markers (one per aircraft: ``target``, or ``target_0`` ...) and cameras
        self._target_bodies = []
        for i in range(k):
            suffix = "" if k == 1 else f"_{i}"
            body = arena.mjcf_model.worldbody.add("body", name=f"target{suffix}")
            body.add(
                "geom",
                name=f"target{suffix}_visual",
                type="cylinder",
                size=[spec.agent.goal_radius, 0.03],
                rgba=[0.1, 0.9, 0.2, 0.5] if k == 1 else [*_AGENT_COLOURS[i % len(_AGENT_COLOURS)], 0.5],
                contype=0,
                conaffinity=0,
                group=2,
            )
            self._target_bodies.append(body)
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
        self._contact_sensors = [
            agent.mjcf_model.sensor.add(
                "contact", name="obstacle_contacts", body1=agent.root_body, data="found", reduce="mindist"
            )
            for agent in self._agents
        ]

        # composer sees one substep per control step; after_compile restores the real timestep
        self._n_sub = int(round(ep.control_period / ep.physics_timestep))
        self.set_timesteps(control_timestep=ep.control_period, physics_timestep=ep.control_period)

        self._predictor = predictor or make_predictor(ep.predictor, ep.horizon, ep.control_period)
        self._horizon = int(self._predictor.horizon)
        # the MPC predictor's per-step call without its input checks (``predict_positions``); its module is loaded
        # whenever such a predictor exists (CasADi is imported on use only)
        mpc = sys.modules.get("deck_sim.control.mpc_predictor")
        self._mpc = mpc is not None and type(self._predictor) is mpc.MPCPredictor
        # the repulsion term's look-ahead (``reward.lookahead_steps``): the episode's own forecast where the scene
        # built it as the look-ahead's predictor, else a predictor of its own, so that the reward is the same
        # whatever the agent observes (a predictor handed in is never taken for the scene's)
        r = spec.reward
        self._lookahead, self._lookahead_predictor = r.lookahead_steps, None
        if self._lookahead and (predictor is not None or ep.predictor != r.lookahead_predictor):
            self._lookahead_predictor = make_predictor(r.lookahead_predictor, ep.horizon, ep.control_period)
        self._spot_xy = np.array([arena.site(s).xy for s in spec.movers.spots]).reshape(-1, 2)
        self._kinds = np.array(
            [ObstacleKind.PEDESTRIAN if isinstance(m, Pedestrian) else ObstacleKind.WHEELED for m in self._movers],
            dtype=int,
        )
        self._no_fallback = np.zeros(len(self._kinds), dtype=bool)  # (shared by the fast path's predictions)
        self._mover_half = np.array([m.footprint[1] for m in self._movers]).reshape(-1, 2)
        self._mover_radius_fp = np.array([m.footprint[2] for m in self._movers])
        # what an agent observes as dynamic obstacles: the movers, then (with several agents) the other aircraft
        self._dyn_half, self._dyn_radius = self._mover_half, self._mover_radius_fp
        if k > 1:
            _, agent_half, agent_round = self._agent.footprint
            self._dyn_half = np.concatenate([self._mover_half, np.repeat(np.asarray(agent_half)[None], k - 1, 0)])
            self._dyn_radius = np.concatenate([self._mover_radius_fp, np.full(k - 1, float(agent_round))])
        self._agent_frame = spec.episode.frame == "agent"  # observation and action in the agent's axes
        self._route_steps = spec.episode.route_steps  # points of the observed route; 0: not observed
        self._obs_config = ObservationConfig(
            horizon=self._horizon,
            bounds=arena.bounds,
            mover_half=self._dyn_half,
            mover_radius=self._dyn_radius,
            predicted_from_agent=spec.episode.predicted_frame == "agent",
            approach_dt=ep.control_period if spec.episode.predicted_approach else 0.0,
            obstacle_shape=spec.episode.obstacle_shape,
            mover_size=self._dyn_half + self._dyn_radius[:, None] if spec.episode.mover_size else None,
            near=spec.episode.near_steps * spec.agent.reach,  # metres of the near field; 0: not observed
            near_obstacles=spec.episode.near_obstacles,
            predicted_near=spec.episode.predicted_near,
            route_steps=self._route_steps,
            static_size=spec.episode.static_size,
            agent_frame=self._agent_frame,
        )
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
        return list(self._stepper.obstacle_names)

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step."""
        return self._n_sub

    def _build_observables(self) -> None:
        m = len(self._statics) + len(self._arena.fixed_obstacle_geoms)
        self._obs_shapes = shapes = observation_shapes(self._obs_config, m, len(self._dyn_half))
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
        self._stepper = FusedStepper(
            physics,
            self._arena,
            self._agents,
            self._movers,
            self._statics,
            self._contact_sensors,
            self._n_sub,
            self.spec.episode.collision_checks,
        )
        self._ctrl_agents = [as_slice(physics.bind(list(a.actuators)).element_id) for a in self._agents]
        # controller constants come from the compiled model, not from copies of the XML's numbers
        if isinstance(self._agent, Aircraft):
            self._aircraft_limits = AircraftLimits(**self._agent.physical_limits(physics))
        self._mover_driver = MoverDriver(
            physics, self.spec, self._movers, self._behaviour, self._spot_xy, self._mover_disc, self._n_agents
        )

    # -- episode set-up --------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> Layout:
        """Draw a non-overlapping layout for one episode.

        Raises:
            LayoutError: naming what could not be placed and why.
        """
        spec = self.spec
        return sample_layout(
            spec,
            self._arena,
            self._statics[0].footprint if spec.static.slotted else None,  # slotted props come first
            self._spot_xy,
            self._mover_spawn_radius,
            [mover.mjcf_model.model for mover in self._movers],
            rng,
        )

    def initialize_episode(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Sample a layout, place everything, plan the movers' first trips and compute the first observation."""
        rng = np.random.default_rng(random_state.randint(2**32 - 1))
        layout = self.sample_layout(rng)
        self.layout = layout
        spec = self.spec
        self._place(physics, layout)
        self._clearance_of = Clearances(
            self._static_fp, layout.mover_xy, self._mover_half, self._mover_radius_fp, spec.agent.radius
        )
        self._mover_driver.start_episode(physics, layout, self._static_fp, self._arena.bounds, rng)
        physics.data.ctrl[:] = 0.0
        physics.forward()

        # episode bookkeeping
        self._state = self._stepper.read_state()
        agent_xy = self._state["xy"][0]
        self._history = np.repeat(self._state["xy"][1:, None, :], spec.episode.history, axis=1)
        self._predictor.reset(self._spot_xy, self._kinds)
        self._prediction = self._predict(physics)
        if self._lookahead_predictor is not None:
            self._lookahead_predictor.reset(self._spot_xy, self._kinds)
        self._dist_target = float(np.linalg.norm(layout.target_xy - agent_xy))
        self._clearances = self._clearance_of(self._state)
        self._repelled = self._repulsion_clearances(physics, self._state, self._clearances)
        self._stepper.start_episode()
        self._reached = self._off_surface = self._diverged = False
        self._terminal = False
        self._reward = rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0)
        self._fallbacks_total = 0
        self._rescued = 0
        self._update_observation()
        self._update_info(physics)

    def _place(self, physics: mjcf.Physics, layout: Layout) -> None:
        """Put the agents, the static obstacles and the target markers where ``layout`` says; the episode's
        static footprints and route graph."""
        if isinstance(self._agent, Aircraft):
            # the attachment frame on the surface: the model's own root sits 1.8 m above it, wheels on the deck
            for agent, xy, yaw in zip(self._agents, layout.agents_xy, layout.agents_yaw, strict=True):
                agent.set_pose(physics, np.array([*xy, 0.0]), yaw_quat(yaw))
                agent.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
        else:
            # a pedestrian's slide joints live in its attachment frame: keep that frame unrotated (world axes)
            self._agent.set_pose(physics, np.array([*layout.agent_xy, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
            physics.bind(list(self._agent.joints)).qpos = 0.0
            physics.bind(list(self._agent.joints)).qvel = 0.0
        for prop, xy, yaw in zip(self._statics, layout.static_xy, layout.static_yaw, strict=True):
            prop.set_pose(physics, np.array([*xy, 0.0]), yaw_quat(yaw))
        for body, xy in zip(self._target_bodies, layout.targets_xy, strict=True):
            physics.bind(body).pos = np.array([*xy, 0.0])

        # fixed obstacle footprints this episode (statics + the arena's own)
        self._static_fp = static_footprints(layout, [p.footprint for p in self._statics], self._arena.fixed_obstacles())
        if self._route_steps > 0:
            self._route_graph = VisibilityGraph(
                self._static_fp, self.spec.agent.radius + ROUTE_MARGIN, self._arena.bounds
            )

    # -- one control step ----------------------------------------------------------------------------------
    def before_step(self, physics: mjcf.Physics, action: np.ndarray, random_state: np.random.RandomState) -> None:
        """Check the action, set every actuator, and run all physics substeps but composer's last one."""
        a0, a1 = checked_action(action)
        spec, st = self.spec, self._state
        if isinstance(self._agent, Aircraft):
            self._drive_aircraft(0, a0, a1)
        else:
            a0, a1 = self._to_world(0, a0, a1)
            period, reach = spec.episode.control_period, spec.agent.reach
            displacement = np.array([a0, a1]) * reach
            self._d.ctrl[self._ctrl_agents[0]] = track_velocity(displacement[None], period, reach / period)[0]
        self._mover_driver.command(self._d.time, st)
        self._stepper.substeps()  # composer runs the final one

    def _to_world(self, i: int, a0: float, a1: float) -> tuple[float, float]:
        """Agent i's action (a0, a1) in the world's axes: as given in the world frame; in the agent frame, ahead
        and to the left turned by its yaw (``agent_to_world`` on two floats)."""
        if not self._agent_frame:
            return a0, a1
        yaw = float(self._state["yaw"][i])
        c, s = math.cos(yaw), math.sin(yaw)
        return c * a0 - s * a1, s * a0 + c * a1

    def _drive_aircraft(self, i: int, a0: float, a1: float) -> None:
        """Write aircraft i's controls (steer, thrust, brakes) for its action (a0, a1) in the task's frame."""
        a0, a1 = self._to_world(i, a0, a1)
        st, reach = self._state, self.spec.agent.reach
        cmd = track_displacement(
            a0 * reach,
            a1 * reach,
            float(st["yaw"][i]),
            float(st["forward_speed"][i]),
            self.spec.episode.control_period,
            self._aircraft_limits,
        )
        self._d.ctrl[self._ctrl_agents[i]] = (cmd.steer, cmd.thrust, cmd.brake, cmd.brake)

    def after_step(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Read the new state, update histories, prediction, reward, termination and observation."""
        stepper = self._stepper
        stepper.check_contacts()
        spec = self.spec
        st = stepper.read_state()
        self._diverged = stepper.diverged(st["vel"])
        on_surface, lost = stepper.surface(st["xy"])
        agent_on_surface = on_surface[0]
        if lost:  # rare: a crash pushed a mover off the surface
            self._rescued += self._mover_driver.rescue(physics, lost, st)
            st = stepper.read_state()
        self._state = st
        agent_xy = st["xy"][0]
        self._history[:, :-1] = self._history[:, 1:]  # shift in place, newest last
        self._history[:, -1] = st["xy"][1:]
        self._prediction = self._predict(physics)

        to_target = self.layout.target_xy - agent_xy
        dist = math.sqrt(to_target.dot(to_target))  # as np.linalg.norm computes it
        clear = self._clearance_of(st)
        repelled = self._repulsion_clearances(physics, st, clear)
        r = spec.reward
        collided = stepper.collided_with is not None
        self._reached = dist <= spec.agent.goal_radius and not collided
        self._off_surface = not agent_on_surface
        failed = collided or self._off_surface
        if self._diverged:
            self._reward = rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            r1 = rewards.attraction(self._dist_target, dist, r.attraction_min, r.attraction_max, r.progress_deadband)
            r2 = rewards.repulsion(
                self._repelled,
                repelled,
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
        self._dist_target, self._clearances, self._repelled = dist, clear, repelled
        self._terminal = self._reached or failed or self._diverged
        if self._diverged:
            log.warning("%s: physics diverged at t=%.2f s; episode ended", spec.name, physics.data.time)
        self._update_observation()
        self._update_info(physics)

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
    def _mover_footprints(self, st: dict[str, np.ndarray]) -> Footprints:
        return Footprints(st["xy"][1:], self._mover_half, st["yaw"][1:], self._mover_radius_fp)

    def _repulsion_clearances(self, physics: mjcf.Physics, st: dict[str, np.ndarray], clear: np.ndarray
                              ) -> np.ndarray:
        """The clearances (k,) that r2 reads, metres: ``clear`` itself, or with ``reward.lookahead_steps`` = K > 0
        each mover's clearance less how much nearer its centre comes to the agent's within K steps (the agent
        carried on at its current velocity, the mover along the look-ahead forecast), never more than now."""
        if not self._lookahead or not len(self._kinds):
            return clear
        forecast = (
            self._prediction.positions
            if self._lookahead_predictor is None
            else self._predict(physics, self._lookahead_predictor).positions
        )[:, : self._lookahead]
        xy, n = st["xy"], len(self._kinds)
        out = clear.copy()
        out[-n:] = rewards.lookahead_clearances(
            clear[-n:], xy[0], st["vel"][0], xy[1:], forecast, self.spec.episode.control_period
        )
        return out

    def _predict(self, physics: mjcf.Physics, predictor: Predictor | None = None) -> Prediction:
        """The forecast of the episode's predictor, or of ``predictor`` (the reward's look-ahead)."""
        if predictor is not None:
            future = self.simulate_future(physics, predictor.horizon) if predictor.needs_future else None
            tracks = ObstacleTracks(
                dt=self.spec.episode.control_period, positions=self._history, kinds=self._kinds, future=future
            )
            return predictor.predict(tracks)
        if not len(self._kinds):
            return Prediction(np.zeros((0, self._horizon, 2)), np.zeros(0, dtype=bool))
        if type(self._predictor) is ConstantVelocity:
            # the scenes' default predictor, on the hot path: the task's own history is well formed (MuJoCo resets
            # a diverged state), so ``predict``'s input checks are skipped; the same numbers
            p, dt, hist = self._predictor, self.spec.episode.control_period, self._history
            if not math.isfinite(hist.sum()):  # never expected: let ``predict`` name the problem
                return p.predict(ObstacleTracks(dt=dt, positions=hist, kinds=self._kinds))
            velocity = least_squares_velocity(hist, dt, p.window)
            return Prediction(constant_velocity_rollout(hist[:, -1, :], velocity, dt, p.horizon), self._no_fallback)
        if self._mpc:
            return self._predictor.predict_positions(self._history, self.spec.episode.control_period)
        future = self.simulate_future(physics, self._horizon) if self._predictor.needs_future else None
        tracks = ObstacleTracks(
            dt=self.spec.episode.control_period, positions=self._history, kinds=self._kinds, future=future
        )
        return self._predictor.predict(tracks)

    def simulate_future(self, physics: mjcf.Physics, steps: int) -> np.ndarray:
        """The movers' positions over the next ``steps`` control steps, (n, steps, 2), by simulating ahead.

        A copy of the physics state and of the movers' behaviour (its random generator included) is stepped
        forward with the agent (every agent) braking where it stands; the real episode is untouched. Exact while
        the movers do not react to the agent.
        """
        d_saved = mujoco.MjData(self._m)
        mujoco.mj_copyData(d_saved, self._m, self._d)
        behaviour_saved = self._behaviour.snapshot()
        out = np.zeros((len(self._movers), steps, 2))
        try:
            d = self._d
            for ctrl in self._ctrl_agents:
                d.ctrl[ctrl] = (0.0, 0.0, 1.0, 1.0) if isinstance(self._agent, Aircraft) else 0.0
            st = self._stepper.read_state()
            for k in range(steps):
                self._mover_driver.command(d.time, st)
                mujoco.mj_step(self._m, d, nstep=self._n_sub)
                st = self._stepper.read_state()
                out[:, k] = st["xy"][self._n_agents :]
        finally:
            mujoco.mj_copyData(self._d, self._m, d_saved)
            self._behaviour.restore(behaviour_saved)
        return out

    def _update_observation(self) -> None:
        # ``st`` holds fresh arrays every step that nothing writes to afterwards: the agent's rows are handed out
        # as views (``position``, ``velocity``)
        st = self._state
        agent_xy = st["xy"][0]
        self._obs = build_observation(
            self._obs_config,
            agent_xy,
            float(st["yaw"][0]),
            st["vel"][0],
            self.layout.target_xy,
            self._static_fp,
            st["xy"][1:],
            st["yaw"][1:],
            self._prediction.positions,
            self.route_points(agent_xy) if self._route_steps > 0 else None,
        )

    def _update_info(self, physics: mjcf.Physics) -> None:
        st, fallbacks = self._state, self._prediction.n_fallbacks
        self._fallbacks_total += fallbacks
        self.last_info = {
            "time": float(self._d.time),
            "position": st["xy"][0].copy(),  # (copies: a caller may write to what it is given)
            "heading": float(st["yaw"][0]),
            "speed": float(st["forward_speed"][0]),
            "distance_to_goal": float(self._dist_target),
            "min_clearance": float(self._clearances.min(initial=np.inf)),
            "reward_terms": self._reward.as_dict(),
            "collision": self._stepper.collided_with,
            "reached_goal": bool(self._reached),
            "left_surface": bool(self._off_surface),
            "diverged": bool(self._diverged),
            "predictor": self._predictor.name,
            "predictor_fallbacks": fallbacks,
            "predictor_fallbacks_total": int(self._fallbacks_total),
            "movers_rescued": int(self._rescued),
            "mover_positions": st["xy"][1:].copy(),
            "mover_yaw": st["yaw"][1:].copy(),
            "prediction": self._prediction.positions.copy(),
        }

    def action_from_world(self, action: np.ndarray, agent: int = 0) -> np.ndarray:
        """A world-frame action (2,) of the agent (of aircraft ``agent`` in a multi-agent scene) in this task's
        action frame (``episode.frame``), clipped to [-1, 1]^2.

        Identity in the world frame; in the agent frame it is turned by minus the agent's current yaw, which is
        exact (no clipping) for actions in the unit disc, as every planner's are. The scripted and classical
        planners plan in the world and go through this (``policies.ScriptedPolicy``)."""
        action = np.asarray(action, dtype=np.float64)
        if not self._agent_frame:
            return action
        return np.clip(world_to_agent(action, float(self._state["yaw"][agent])), -1.0, 1.0)

    def route_points(self, agent_xy: np.ndarray, target_xy: np.ndarray | None = None) -> np.ndarray:
        """(``route_steps``, 2) world points ``k * agent.reach`` metres (k = 1, 2, ...) along the shortest path
        from ``agent_xy`` to ``target_xy`` (default: the agent's target) around this episode's static obstacles
        (scene field ``episode.route_steps``); the target itself beyond the path's end. Where the graph finds no
        path (the agent boxed in, or inside grown obstacles with no way out), the straight line to the target
        stands in for it, as in the scripted planner."""
        if self._route_graph is None:
            raise RuntimeError("the scene's episode.route_steps is 0: no route is observed")
        target = self.layout.target_xy if target_xy is None else target_xy
        try:
            path = self._route_graph.shortest_path(agent_xy, target)
        except NoPathError:
            path = np.stack([agent_xy, target])
        return points_along(path, self.spec.agent.reach * np.arange(1, self._route_steps + 1))

    def _agent_observation(self, agent: int) -> dict[str, np.ndarray]:
        """Aircraft ``agent``'s observation of this step (one aircraft here: ``agent`` 0)."""
        if agent != 0:
            raise ValueError(f"scene {self.spec.name!r} has one aircraft, no aircraft {agent}")
        return self._obs

    def observed_view(self, forecast: bool = True, agent: int = 0) -> PlannerView:
        """What a planner may plan from when it sees only this step's observation (the ``planner`` regime's
        teacher): the obstacles' footprints, positions and headings as observed, and the movers' predicted
        positions as observed (``forecast``; without it, or without a ``predicted`` part, every mover is taken to
        stand where it is). The footprints are the observed rectangles of half-length and half-width, rounding
        included, so they contain the true rounded ones. What never changes during an episode and is no state of
        the world comes from the scene as in ``planner_view``: the agent's own size, body and limits, the goal
        radius, the surface's bounds, the step's reach and period. ``agent``: whose observation (several
        aircraft: ``aircraft_<agent>``'s).

        Raises:
            ValueError: The observation lacks the footprints (scene fields ``episode.static_size``,
                ``episode.mover_size`` and ``episode.obstacle_shape`` must be on).
        """
        obs = self._agent_observation(agent)
        missing = [f"episode.{field}" for field, key in (("static_size", "static_size"), ("mover_size",
                   "dynamic_size"), ("obstacle_shape", "dynamic_heading")) if key not in obs]
        if missing:
            raise ValueError(f"scene {self.spec.name!r}: a planner on the observation needs every obstacle's "
                             f"footprint in it; turn on {', '.join(missing)}")
        xy = np.array(obs["position"], dtype=float)
        yaw = math.atan2(float(obs["heading"][1]), float(obs["heading"][0]))

        def world(key: str) -> np.ndarray:  # an observed vector (or array of them) in the world's axes
            v = np.asarray(obs[key], dtype=float)
            return agent_to_world(v, yaw) if self._agent_frame and key in TURNED_KEYS else v

        def angle(key: str) -> np.ndarray:
            heading = world(key)
            return np.arctan2(heading[:, 1], heading[:, 0])

        n_static, n_movers = len(obs["static_obstacles"]), len(obs["dynamic_obstacles"])
        statics = Footprints(xy + world("static_obstacles"), np.array(obs["static_size"], dtype=float),
                             angle("static_heading"), np.zeros(n_static))
        mover_xy = xy + world("dynamic_obstacles")
        movers = Footprints(mover_xy, np.array(obs["dynamic_size"], dtype=float), angle("dynamic_heading"),
                            np.zeros(n_movers))
        if forecast and "predicted" in obs:
            origin = xy if self._obs_config.predicted_from_agent else mover_xy[:, None]
            future = origin + world("predicted")
        else:
            future = np.repeat(mover_xy[:, None], max(self._horizon, 1), axis=1)
        return PlannerView(
            agent_xy=xy,
            agent_yaw=yaw,
            agent_speed=float(np.dot(world("velocity"), obs["heading"])),
            agent_radius=self.spec.agent.radius,
            target_xy=xy + world("target"),
            goal_radius=self.spec.agent.goal_radius,
            statics=statics,
            movers=movers,
            mover_future=future,
            bounds=self._arena.bounds,
            reach=self.spec.agent.reach,
            period=self.spec.episode.control_period,
            agent_circles=self._agent_circles,
            agent_limits=self._aircraft_limits,
        )

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
