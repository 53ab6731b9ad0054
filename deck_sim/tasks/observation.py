"""The navigation task's observation (paper eq. 7-8), a pure function of the step's arrays: no physics, no composer.

Observation (all relative vectors in the world frame, metres, or in the agent's own with ``episode.frame =
"agent"``; obstacles nearest first):
    ``target`` (2) target minus agent; ``static_obstacles`` (m, 2) static obstacles (on the deck the island is
    the last of m = 15 + 1) minus agent; ``dynamic_obstacles`` (n, 2) movers now minus agent; ``predicted``
    (n, N, 2) predicted mover positions minus agent (absent when N = 0; minus each mover's position now with
    ``episode.predicted_frame = "mover"``; ``predicted_approach`` (n, 2) with ``episode.predicted_approach``, each
    mover's closest approach on its forecast, ``closest_approach``; ``predicted_near`` (n, N, 2) with
    ``episode.predicted_near``, the forecast at the near field's scale, ``near_forecast``); ``position`` (2) the
    agent's own
    position (where the deck edges are); ``velocity`` (2) m/s; ``heading`` (2) cos and sin of yaw. Options of
    the scene's ``[episode]`` add the obstacles' shapes (``obstacle_shape``), the movers' sizes (``mover_size``),
    the static obstacles' footprints (``static_size``: ``static_size`` and ``static_heading``),
    the target and edges clipped to a few steps' reach (``near_steps``: ``target_near``, ``edge_near``; with
    ``near_obstacles`` also every obstacle's nearest point clipped to it, ``static_near``, ``dynamic_near``) and the
    next points of the shortest way round the static obstacles (``route_steps``: ``route``).

``observation_shapes`` gives every key's shape in the order ``build_observation`` fills them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from deck_sim.geometry import Footprints, clip_length, world_to_agent

TURNED_KEYS = (
    "target",
    "static_obstacles",
    "dynamic_obstacles",
    "predicted",
    "static_nearest",
    "dynamic_nearest",
    "dynamic_heading",
    "static_heading",
    "target_near",
    "static_near",
    "dynamic_near",
    "predicted_near",
    "route",
    "velocity",
)
"""Observation keys holding world vectors (..., 2) that ``episode.frame = "agent"`` turns into the agent's axes."""


@dataclass(frozen=True, eq=False)
class ObservationConfig:
    """What one task's observation holds, and the fixed sizes it reads.

    Attributes:
        horizon: predicted steps N of every mover; 0 leaves ``predicted`` out.
        bounds: ((xmin, ymin), (xmax, ymax)) of the walkable surface, metres (read by ``edge_near``).
        mover_half: (n, 2) half-extents of every mover's footprint, metres.
        mover_radius: (n,) rounding radius of every mover's footprint, metres.
        predicted_from_agent: ``predicted`` relative to the agent (``episode.predicted_frame = "agent"``), else
            to each mover's position now.
        approach_dt: the control period, seconds, with which ``predicted_approach`` is computed
            (``episode.predicted_approach``); 0 leaves it out.
        obstacle_shape: observe ``static_nearest``, ``dynamic_nearest`` and ``dynamic_heading``.
        mover_size: (n, 2) every mover's half-length and half-width, rounding radius included, metres, observed
            as ``dynamic_size``; None leaves it out.
        near: radius of the near field, metres (``episode.near_steps * agent.reach``); 0 leaves ``target_near``
            and ``edge_near`` out.
        near_obstacles: with ``near`` > 0, observe ``static_near`` and ``dynamic_near``.
        predicted_near: with ``near`` > 0 and ``horizon`` > 0, observe ``predicted_near`` (``near_forecast``).
        route_steps: points of ``route``; 0 leaves it out.
        static_size: observe every static obstacle's footprint: ``static_size`` (m, 2), its half-length and
            half-width, rounding radius included, metres, and ``static_heading`` (m, 2), the cos and sin of its
            long axis, in the order of ``static_obstacles``.
        agent_frame: turn the relative vectors (``TURNED_KEYS``) into the agent's axes.
    """

    horizon: int
    bounds: np.ndarray
    mover_half: np.ndarray
    mover_radius: np.ndarray
    predicted_from_agent: bool = True
    approach_dt: float = 0.0
    obstacle_shape: bool = False
    mover_size: np.ndarray | None = None
    near: float = 0.0
    near_obstacles: bool = False
    predicted_near: bool = False
    route_steps: int = 0
    static_size: bool = False
    agent_frame: bool = False

    @property
    def observes_near_forecast(self) -> bool:
        """Whether ``predicted_near`` is observed: asked for, with a near field and a forecast."""
        return self.predicted_near and self.near > 0 and self.horizon > 0


def closest_approach(now: np.ndarray, forecast: np.ndarray, velocity: np.ndarray, dt: float) -> np.ndarray:
    """Each mover's closest approach to the agent carried on at ``velocity``: (n, 2), the time (seconds from now)
    and the distance between centres (metres) where it is least over now and the forecast's steps (the earliest
    of equal ones).

    Args:
        now: (n, 2) the movers' positions now minus the agent's, metres.
        forecast: (n, N, 2) their forecast positions minus the agent's position now, one every ``dt`` seconds.
        velocity: (2,) the agent's velocity, m/s.
    """
    steps = np.arange(forecast.shape[1] + 1) * dt
    track = np.concatenate([now[:, None], forecast], axis=1) - steps[:, None] * velocity  # (n, N + 1, 2)
    dist = np.sqrt(np.einsum("ijk,ijk->ij", track, track))
    first = dist.argmin(axis=1)
    return np.stack([steps[first], dist[np.arange(len(dist)), first]], axis=1)


def near_forecast(nearest: np.ndarray, now: np.ndarray, forecast: np.ndarray, near: float) -> np.ndarray:
    """Each mover's forecast at the near field's scale: (n, N, 2), the nearest point of its footprint now, moved
    by its predicted displacement at each forecast step, with its length clipped to ``near`` metres; relative to
    the agent's position now (the frame of ``predicted``). The footprint is carried without turning (the forecast
    holds positions, not headings), so for a mover that turns within the forecast the point is approximate.

    Args:
        nearest: (n, 2) the nearest point of each mover's footprint minus the agent's position, metres.
        now: (n, 2) the movers' positions now, metres (any origin shared with ``forecast``).
        forecast: (n, N, 2) their forecast positions, metres, same origin as ``now``.
        near: radius of the near field, metres (> 0).
    """
    return clip_length(nearest[:, None] + (forecast - now[:, None]), near)


def observation_shapes(config: ObservationConfig, n_static: int, n_movers: int) -> dict[str, tuple[int, ...]]:
    """Shape of every observation key for ``n_static`` static obstacles and ``n_movers`` movers, in order."""
    m, n = n_static, n_movers
    shapes = {"target": (2,), "static_obstacles": (m, 2), "dynamic_obstacles": (n, 2)}
    if config.horizon > 0:
        shapes["predicted"] = (n, config.horizon, 2)
        if config.approach_dt > 0:
            shapes["predicted_approach"] = (n, 2)
    if config.obstacle_shape:
        shapes.update({"static_nearest": (m, 2), "dynamic_nearest": (n, 2), "dynamic_heading": (n, 2)})
    if config.mover_size is not None:
        shapes["dynamic_size"] = (n, 2)
    if config.static_size:
        shapes.update({"static_size": (m, 2), "static_heading": (m, 2)})
    if config.near > 0:
        shapes.update({"target_near": (2,), "edge_near": (4,)})
        if config.near_obstacles:
            shapes.update({"static_near": (m, 2), "dynamic_near": (n, 2)})
        if config.observes_near_forecast:
            shapes["predicted_near"] = (n, config.horizon, 2)
    if config.route_steps > 0:
        shapes["route"] = (config.route_steps, 2)
    shapes.update({"position": (2,), "velocity": (2,), "heading": (2,)})
    return shapes


def build_observation(
    config: ObservationConfig,
    agent_xy: np.ndarray,
    agent_yaw: float,
    agent_velocity: np.ndarray,
    target_xy: np.ndarray,
    statics: Footprints,
    mover_xy: np.ndarray,
    mover_yaw: np.ndarray,
    predicted: np.ndarray,
    route: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The observation of one step, keys in the order of ``observation_shapes``.

    Args:
        config: the task's observation options and fixed sizes.
        agent_xy: (2,) the agent's position, metres; observed as ``position`` (this very array).
        agent_yaw: the agent's heading, radians.
        agent_velocity: (2,) the agent's planar velocity in the world's axes, m/s; observed as ``velocity`` (this
            very array in the world frame).
        target_xy: (2,) the target, metres.
        statics: the m static obstacles' footprints (world frame, metres).
        mover_xy: (n, 2) the movers' positions now, metres.
        mover_yaw: (n,) the movers' headings, radians.
        predicted: (n, N, 2) the movers' predicted world positions, metres (read when ``config.horizon`` > 0).
        route: (route_steps, 2) world points of the way to the target, metres (read when ``config.route_steps``
            > 0).
    """
    statics_rel = statics.centers - agent_xy
    order_s = np.einsum("ij,ij->i", statics_rel, statics_rel).argsort(kind="stable")
    movers = mover_xy - agent_xy
    order_m = np.einsum("ij,ij->i", movers, movers).argsort(kind="stable")
    obs = {
        "target": target_xy - agent_xy,
        "static_obstacles": statics_rel[order_s],
        "dynamic_obstacles": movers[order_m],
    }
    if config.horizon > 0:
        origin = agent_xy if config.predicted_from_agent else mover_xy[order_m][:, None]
        obs["predicted"] = predicted[order_m] - origin
        if config.approach_dt > 0:
            obs["predicted_approach"] = closest_approach(
                movers[order_m], predicted[order_m] - agent_xy, agent_velocity, config.approach_dt
            )
    near, near_obstacles = config.near, config.near_obstacles
    static_nearest = dynamic_nearest = None
    forecast_near = config.observes_near_forecast
    if config.obstacle_shape or (near > 0 and near_obstacles):
        static_nearest = statics.nearest_points(agent_xy)[order_s] - agent_xy
    if config.obstacle_shape or (near > 0 and near_obstacles) or forecast_near:
        mover_fp = Footprints(mover_xy, config.mover_half, mover_yaw, config.mover_radius)
        dynamic_nearest = mover_fp.nearest_points(agent_xy)[order_m] - agent_xy
    if config.obstacle_shape:
        obs["static_nearest"] = static_nearest
        obs["dynamic_nearest"] = dynamic_nearest
        yaw = mover_yaw[order_m]
        obs["dynamic_heading"] = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    if config.mover_size is not None:
        obs["dynamic_size"] = config.mover_size[order_m]
    if config.static_size:
        obs["static_size"] = (statics.half + statics.radius[:, None])[order_s]
        yaw = statics.yaw[order_s]
        obs["static_heading"] = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    if near > 0:
        to_target = obs["target"]
        length = math.hypot(float(to_target[0]), float(to_target[1]))
        obs["target_near"] = to_target * (near / length) if length > near else to_target.copy()
        lo, hi = config.bounds
        obs["edge_near"] = np.clip(np.concatenate([agent_xy - lo, hi - agent_xy])[[0, 2, 1, 3]], 0.0, near)
        if near_obstacles and static_nearest is not None and dynamic_nearest is not None:
            obs["static_near"] = clip_length(static_nearest, near)
            obs["dynamic_near"] = clip_length(dynamic_nearest, near)
        if forecast_near and dynamic_nearest is not None:
            obs["predicted_near"] = near_forecast(dynamic_nearest, mover_xy[order_m], predicted[order_m], near)
    if config.route_steps > 0:
        obs["route"] = route - agent_xy
    obs["position"] = agent_xy
    obs["velocity"] = agent_velocity
    obs["heading"] = np.array([math.cos(agent_yaw), math.sin(agent_yaw)])
    if config.agent_frame:  # every relative vector turned by minus the yaw (new arrays: the inputs stay as they are)
        for key in TURNED_KEYS:
            if key in obs:
                obs[key] = world_to_agent(obs[key], agent_yaw)
    return obs
