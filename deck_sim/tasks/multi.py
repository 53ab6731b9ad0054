"""Several aircraft at once: the navigation task with ``agents.count`` learning aircraft (dm_control soccer style).

Every aircraft ``aircraft_i`` has its own start, target, observation and reward (eq. 10-16). Each sees the scene's
movers and then the other aircraft as its dynamic obstacles: ``dynamic_obstacles``, ``predicted`` and the shape
keys hold n + k - 1 rows, the movers first (as in the single-agent scene), then the other aircraft in index order,
each sorted nearest first as any observation is. One predictor call per step predicts the movers and every
aircraft; the aircraft's targets join the movers' spots as the intents the MPC predictor weighs.

The dm_control interface: ``action_spec`` is a list of k specs and ``step`` takes k actions (a list of pairs, or an
array (k, 2)); observations are namespaced ``aircraft_i:<key>`` with the single-agent keys (a colon, because the
aircraft entities' own observables, disabled, are named ``aircraft_i/position`` and so on); the reward and the
discount are arrays (k,).

An aircraft that reaches its target, collides or leaves the surface is done, and leaves the deck at once: a
catapult launches it, the launch crew takes it over at its queue spot, a tractor tows a damaged one away. The task
puts it at rest on its own stand of an off-deck apron (``HANGAR_X``: a strip of ground beyond the stern, out of the
movers' routes and every camera's view of the deck), braked. It stays in the other aircraft's observations as a
dynamic obstacle far behind the stern (the observation's rows are fixed; sorted nearest first, it comes last), its
reward and discount are 0 from then on, and its actions are ignored. The episode ends when every aircraft is done,
at the time limit, or when the physics diverges. A collision between two aircraft is a collision for both: each
one's contact names the other.

Why it leaves rather than parks where it stopped: the movers route round the static obstacles of the episode's start
(their route graphs are built once per episode), and an aircraft standing at a catapult or a queue spot would stand
in their routes for the rest of the episode, holding them (they yield to aircraft) and, through them, the aircraft
still taxiing.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np
from dm_control import mjcf
from dm_control.composer.observation import observable
from dm_env import specs

from deck_sim.control.prediction import Predictor
from deck_sim.geometry import Footprints
from deck_sim.scenes import SceneSpec
from deck_sim.tasks import rewards
from deck_sim.tasks.actions import InvalidActionError, checked_action
from deck_sim.tasks.navigate import Navigate
from deck_sim.tasks.observation import build_observation, observation_shapes
from deck_sim.tasks.physics_step import Clearances
from deck_sim.types import ObstacleKind, PlannerView

__all__ = ["MultiNavigate", "checked_actions"]

_BRAKED = (0.0, 0.0, 1.0, 1.0)
"""An aircraft's controls while it stands: no steer, no thrust, full brakes."""

HANGAR_X = -60.0
"""Metres: x of the first stand of the off-deck apron where aircraft that are done wait (the deck's stern is at
x = 0); aircraft i stands at (``HANGAR_X`` - ``HANGAR_SPACING`` * i, 0), heading along x."""
HANGAR_SPACING = 40.0
"""Metres between two stands of the apron (more than an aircraft's length and span)."""


def checked_actions(actions: Any, names: list[str], active: list[bool]) -> list[tuple[float, float] | None]:
    """Every active agent's action as two floats (None for an agent that is done, whose action is not read).

    ``actions`` is a sequence of one action per agent, in the order of ``names``, or an array (k, 2).

    Raises:
        InvalidActionError: not one action per agent, or an active agent's action is not a finite pair in
            [-1, 1] (the message names the agent); nothing is applied.
    """
    k = len(names)
    if isinstance(actions, dict):
        raise InvalidActionError(
            f"actions must be a sequence of {k} actions in the order {names}, got a dict (deck_sim.multiagent's "
            "ParallelEnv takes a dict)"
        )
    if isinstance(actions, np.ndarray) and actions.ndim == 2:
        actions = list(actions)
    try:
        n = len(actions)
    except TypeError:
        raise InvalidActionError(f"actions must be a sequence of {k} actions, got {type(actions).__name__}") from None
    if n != k or (isinstance(actions, np.ndarray) and actions.ndim != 2):
        shape = getattr(actions, "shape", n)
        raise InvalidActionError(f"actions must hold one action per aircraft ({k}: {names}), got {shape}")
    out: list[tuple[float, float] | None] = []
    for name, action, on in zip(names, actions, active, strict=True):
        if not on:
            out.append(None)
            continue
        try:
            out.append(checked_action(action))
        except InvalidActionError as err:
            raise InvalidActionError(f"{name}: {err}") from None
    return out


class MultiNavigate(Navigate):
    """Several aircraft reach their own targets among static obstacles, movers and each other.

    Args:
        spec: a scene with ``agents.count`` above 1 (``deck1-multi``, ``deck2-multi``).
        predictor: overrides the predictor named by ``spec.episode.predictor``.

    Raises:
        ValueError: the scene has one agent (load it as ``Navigate``).
    """

    def __init__(self, spec: SceneSpec, predictor: Predictor | None = None) -> None:
        if not spec.multi_agent:
            raise ValueError(f"scene {spec.name!r} has one agent (agents.count 1): use Navigate")
        super().__init__(spec, predictor=predictor)
        k, n = self._n_agents, len(self._movers)
        # the predictor sees the movers, then every aircraft
        self._kinds = np.concatenate([self._kinds, np.full(k, ObstacleKind.WHEELED)]).astype(int)
        self._no_fallback = np.zeros(n + k, dtype=bool)
        self._dyn_rows = np.r_[k : k + n, 0:k]
        """State rows of the predicted vehicles: the movers, then the aircraft."""
        others = [[j for j in range(k) if j != i] for i in range(k)]
        self._view_rows = [np.r_[i, k : k + n, others[i]].astype(int) for i in range(k)]
        """Per aircraft, the state rows it sees: itself, then its dynamic obstacles (movers, other aircraft)."""
        self._pred_rows = [np.r_[0:n, [n + j for j in others[i]]].astype(int) for i in range(k)]
        """Per aircraft, the prediction's rows of its dynamic obstacles."""
        # the apron the aircraft that are done wait on: ground for their wheels only (as the deck's surface)
        length = HANGAR_SPACING * k
        self._arena.mjcf_model.worldbody.add(
            "geom",
            name="apron",
            type="box",
            pos=[HANGAR_X + HANGAR_SPACING / 2 - length / 2, 0.0, -0.5],
            size=[length / 2, HANGAR_SPACING / 2, 0.5],
            contype=1,
            conaffinity=1,
            condim=3,
            friction=[1.0, 0.005, 0.0001],
            group=3,
            rgba=[0.28, 0.29, 0.31, 1.0],
        )
        self._stands = np.array([[HANGAR_X - HANGAR_SPACING * i, 0.0] for i in range(k)])
        self._agent_joints = [list(a.mjcf_model.find_all("joint")) for a in self._agents]

    # -- composer plumbing ---------------------------------------------------------------------------------
    @property
    def agent_names(self) -> list[str]:
        """The aircraft's names, ``aircraft_0`` ...: the prefixes of their observations."""
        return [a.mjcf_model.model for a in self._agents]

    @property
    def agents(self) -> list:
        """The aircraft's entities."""
        return list(self._agents)

    @property
    def n_agents(self) -> int:
        """How many aircraft act."""
        return self._n_agents

    def _build_observables(self) -> None:
        m = len(self._statics) + len(self._arena.fixed_obstacle_geoms)
        self._obs_shapes = shapes = observation_shapes(self._obs_config, m, len(self._dyn_half))
        self._obs_all = [{key: np.zeros(v) for key, v in shapes.items()} for _ in range(self._n_agents)]
        self._obs = self._obs_all[0]
        self._task_observables = {}
        for i, name in enumerate(a.mjcf_model.model for a in self._agents):
            for key in shapes:
                obs = observable.Generic(lambda physics, i=i, key=key: self._obs_all[i][key])
                obs.enabled = True
                self._task_observables[f"{name}:{key}"] = obs

    def action_spec(self, physics: mjcf.Physics) -> list[specs.BoundedArray]:
        """One spec per aircraft, in index order: (x, y) in [-1, 1]^2 as in the single-agent task."""
        return [
            specs.BoundedArray((2,), np.float64, -1.0, 1.0, name=f"{name}: dx\tdy") for name in self.agent_names
        ]

    def get_reward_spec(self) -> specs.Array:
        """One reward per aircraft."""
        return specs.Array((self._n_agents,), np.float64, name="reward")

    def get_discount_spec(self) -> specs.BoundedArray:
        """One discount per aircraft."""
        return specs.BoundedArray((self._n_agents,), np.float64, 0.0, 1.0, name="discount")

    # -- episode set-up --------------------------------------------------------------------------------------
    def _view(self, st: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
        """The state as aircraft i sees it: its own row first, then its dynamic obstacles' rows."""
        rows = self._view_rows[i]
        return {"xy": st["xy"][rows], "yaw": st["yaw"][rows]}

    def initialize_episode(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Sample a layout, place everything, plan the movers' first trips and compute the first observations."""
        rng = np.random.default_rng(random_state.randint(2**32 - 1))
        layout = self.sample_layout(rng)
        self.layout = layout
        spec, k = self.spec, self._n_agents
        self._place(physics, layout)
        start_xy = np.concatenate([layout.mover_xy, layout.agents_xy])  # in the order of ``_dyn_rows``
        radius = spec.agent.radius
        self._clearance_of = [
            Clearances(self._static_fp, start_xy[self._pred_rows[i]], self._dyn_half, self._dyn_radius, radius)
            for i in range(k)
        ]
        self._mover_driver.start_episode(physics, layout, self._static_fp, self._arena.bounds, rng)
        physics.data.ctrl[:] = 0.0
        physics.forward()

        st = self._state = self._stepper.read_state()
        self._history = np.repeat(st["xy"][self._dyn_rows, None, :], spec.episode.history, axis=1)
        self._predictor.reset(np.concatenate([self._spot_xy, layout.targets_xy]), self._kinds)
        self._prediction = self._predict(physics)
        self._dists = [float(np.linalg.norm(layout.targets_xy[i] - st["xy"][i])) for i in range(k)]
        self._clears = [self._clearance_of[i](self._view(st, i)) for i in range(k)]
        self._stepper.start_episode()
        self._done = [False] * k
        self._outcomes: list[dict[str, Any]] = [self._outcome() for _ in range(k)]
        self._rewards = [rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0) for _ in range(k)]
        self._diverged = self._terminal = False
        self._fallbacks_total = 0
        self._rescued = 0
        self._update_observation()
        self._update_info(physics)

    @staticmethod
    def _outcome() -> dict[str, Any]:
        return {"reached_goal": False, "collision": None, "left_surface": False, "done_time": None,
                "done_position": None}

    # -- one control step ----------------------------------------------------------------------------------
    def before_step(self, physics: mjcf.Physics, action: Any, random_state: np.random.RandomState) -> None:
        """Check every active aircraft's action, set every actuator, and run all physics substeps but composer's
        last one; an aircraft that is done brakes."""
        acts = checked_actions(action, self.agent_names, [not done for done in self._done])
        for i, a in enumerate(acts):
            if a is None:
                self._d.ctrl[self._ctrl_agents[i]] = _BRAKED
            else:
                self._drive_aircraft(i, *a)
        self._mover_driver.command(self._d.time, self._state)
        self._stepper.substeps()

    def after_step(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Read the new state; every aircraft's reward and outcome (those done leave the deck), the histories, the
        prediction and the observations."""
        stepper = self._stepper
        stepper.check_contacts()
        spec, k = self.spec, self._n_agents
        st = stepper.read_state()
        self._diverged = stepper.diverged(st["vel"])
        on_surface, lost = stepper.surface(st["xy"])
        if lost:
            self._rescued += self._mover_driver.rescue(physics, lost, st)
            st = stepper.read_state()
        self._state = st
        r = spec.reward
        weights = (r.w_attraction, r.w_repulsion, r.w_collision, r.w_goal)
        finished: list[int] = []
        for i in range(k):
            if self._done[i] or self._diverged:
                self._rewards[i] = rewards.RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0)
                continue
            to_target = self.layout.targets_xy[i] - st["xy"][i]
            dist = math.sqrt(to_target.dot(to_target))
            clear = self._clearance_of[i](self._view(st, i))
            collided_with = stepper.collisions[i]
            reached = dist <= spec.agent.goal_radius and collided_with is None
            off = not on_surface[i]
            failed = collided_with is not None or off
            r1 = rewards.attraction(self._dists[i], dist, r.attraction_min, r.attraction_max, r.progress_deadband)
            r2 = rewards.repulsion(
                self._clears[i], clear, r.influence_radius, r.repulsion_min, r.repulsion_max, r.progress_deadband
            )
            self._rewards[i] = rewards.total_reward(r1, r2, failed, reached, r.collision, r.goal, weights)
            self._dists[i], self._clears[i] = dist, clear
            if reached or failed:
                self._done[i] = True
                self._outcomes[i] = {
                    "reached_goal": bool(reached),
                    "collision": collided_with,
                    "left_surface": bool(off),
                    "done_time": float(self._d.time),
                    "done_position": st["xy"][i].copy(),
                }
                finished.append(i)
        if finished and not self._diverged:
            self._leave_deck(physics, finished)
            st = self._state = stepper.read_state()
        self._history[:, :-1] = self._history[:, 1:]
        self._history[:, -1] = st["xy"][self._dyn_rows]
        if finished and not self._diverged:
            # an aircraft that left has always stood on its stand, as far as the predictor can tell
            rows = [len(self._movers) + i for i in finished]
            self._history[rows] = st["xy"][finished][:, None, :]
            forget = getattr(self._predictor, "forget", None)
            if forget is not None:
                forget(rows)
        self._prediction = self._predict(physics)
        self._terminal = all(self._done) or self._diverged
        self._update_observation()
        self._update_info(physics)

    def _leave_deck(self, physics: mjcf.Physics, agents: list[int]) -> None:
        """Put the aircraft ``agents`` at rest on their stands of the apron, braked (they are done)."""
        for i in agents:
            agent = self._agents[i]
            agent.set_pose(physics, np.array([*self._stands[i], 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
            agent.set_velocity(physics, velocity=np.zeros(3), angular_velocity=np.zeros(3))
            physics.bind(self._agent_joints[i]).qvel = 0.0
            self._d.ctrl[self._ctrl_agents[i]] = _BRAKED
        mujoco.mj_forward(self._m, self._d)

    def get_reward(self, physics: mjcf.Physics) -> np.ndarray:
        """Eq. 16 for the last step, per aircraft (0 for one that was done before it)."""
        return np.array([terms.total for terms in self._rewards])

    def get_discount(self, physics: mjcf.Physics) -> np.ndarray:
        """Per aircraft: 0 once it is done (and for all on divergence), 1 otherwise."""
        return np.array([0.0 if done or self._diverged else 1.0 for done in self._done])

    # -- observation and information -----------------------------------------------------------------------
    def _update_observation(self) -> None:
        st, layout, pred = self._state, self.layout, self._prediction.positions
        for i in range(self._n_agents):
            rows = self._view_rows[i][1:]
            xy = st["xy"][i]
            self._obs_all[i] = build_observation(
                self._obs_config,
                xy,
                float(st["yaw"][i]),
                st["vel"][i],
                layout.targets_xy[i],
                self._static_fp,
                st["xy"][rows],
                st["yaw"][rows],
                pred[self._pred_rows[i]],
                self.route_points(xy, layout.targets_xy[i]) if self._route_steps > 0 else None,
            )
        self._obs = self._obs_all[0]

    def _update_info(self, physics: mjcf.Physics) -> None:
        st, k = self._state, self._n_agents
        fallbacks = self._prediction.n_fallbacks
        self._fallbacks_total += fallbacks
        agents = []
        for i, name in enumerate(self.agent_names):
            agents.append(
                {
                    "name": name,
                    "position": st["xy"][i].copy(),
                    "heading": float(st["yaw"][i]),
                    "speed": float(st["forward_speed"][i]),
                    "target": self.layout.targets_xy[i].copy(),
                    "target_site": self.layout.target_sites[i],
                    "distance_to_goal": float(self._dists[i]),
                    "min_clearance": float(self._clears[i].min(initial=np.inf)),
                    "reward_terms": self._rewards[i].as_dict(),
                    "done": bool(self._done[i]),
                    **self._outcomes[i],
                }
            )
        self.last_info = {
            "time": float(self._d.time),
            "agents": agents,
            "all_reached": all(a["reached_goal"] for a in agents),
            "diverged": bool(self._diverged),
            "predictor": self._predictor.name,
            "predictor_fallbacks": fallbacks,
            "predictor_fallbacks_total": int(self._fallbacks_total),
            "movers_rescued": int(self._rescued),
            "mover_positions": st["xy"][k:].copy(),
            "mover_yaw": st["yaw"][k:].copy(),
            "prediction": self._prediction.positions.copy(),
        }

    def _agent_observation(self, agent: int) -> dict[str, np.ndarray]:
        if not 0 <= agent < self._n_agents:
            raise ValueError(f"scene {self.spec.name!r} has aircraft 0-{self._n_agents - 1}, no aircraft {agent}")
        return self._obs_all[agent]

    def observation_of(self, i: int) -> dict[str, np.ndarray]:
        """Aircraft i's observation of the current step, with the single-agent keys (copies)."""
        return {key: np.array(v) for key, v in self._obs_all[i].items()}

    def planner_view(self, agent: int = 0) -> PlannerView:
        """Full knowledge of the current step for aircraft ``agent``'s planner: the movers and the other aircraft
        as its moving obstacles, with the task's prediction of each."""
        st, i = self._state, agent
        rows = self._view_rows[i][1:]
        future = self._prediction.positions[self._pred_rows[i]].copy()
        return PlannerView(
            agent_xy=st["xy"][i].copy(),
            agent_yaw=float(st["yaw"][i]),
            agent_speed=float(st["forward_speed"][i]),
            agent_radius=self.spec.agent.radius,
            target_xy=self.layout.targets_xy[i].copy(),
            goal_radius=self.spec.agent.goal_radius,
            statics=self._static_fp,
            movers=Footprints(st["xy"][rows], self._dyn_half, st["yaw"][rows], self._dyn_radius),
            mover_future=future,
            bounds=self._arena.bounds,
            reach=self.spec.agent.reach,
            period=self.spec.episode.control_period,
            agent_circles=self._agent_circles,
            agent_limits=self._aircraft_limits,
        )

    def agent_rows(self) -> np.ndarray:
        """(k, k) the row of aircraft j among the moving obstacles of aircraft i's ``planner_view`` (and of its
        observation before sorting): ``n + j`` for j < i, ``n + j - 1`` for j > i, -1 for j = i."""
        k, n = self._n_agents, len(self._movers)
        rows = np.full((k, k), -1, dtype=int)
        for i in range(k):
            for j in range(k):
                if j != i:
                    rows[i, j] = n + (j if j < i else j - 1)
        return rows
