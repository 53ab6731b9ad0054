"""Planners that need no training, acting on full knowledge of the scene (``PlannerView``).

Four references, each ``reset()`` at an episode's start and ``act(view) -> action`` every step (deck_sim's
policies wrap them into ``act(observation)``): ``ScriptedPlanner`` (below, the solvability reference),
``APFPlanner`` (an artificial potential field), ``AStarPlanner`` (A* over a visibility graph of the static
obstacles and the movers' predicted sweeps, replanned every step) and ``MPCPlanner`` (a CasADi MPC that tracks
the static shortest path and keeps clear of the movers' predicted trajectories). All of them read the movers'
future from ``view.mover_future``: what the task's predictor forecast (the MPC predictor in the evaluation).

``ScriptedPlanner`` is how deck_sim knows a scene is solvable: it plans the shortest path around the static
obstacles (visibility graph, for a disc of the agent's radius plus a margin), follows it by pure pursuit, and
picks each step the fastest speed whose rollout along that path stays clear of every mover's predicted path
(the true future when the task runs the ``oracle`` predictor). It yields by slowing or stopping, never by
leaving its path. Numpy only (with ``deck_sim.geometry``); tested without MuJoCo.

``PrioritisedPlanner`` is the same for several agents at once (the multi-aircraft scenes): the agents plan in
turn, each treating the plans of those before it as their future.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from deck_sim.control.tracking import rollout_displacements
from deck_sim.geometry import Footprints, NoPathError, VisibilityGraph, agent_to_world, points_along
from deck_sim.types import PlannerView


@dataclass
class ScriptedPlanner:
    """Full-knowledge path follower that yields to movers.

    Args:
        margin: metres of clearance kept from static obstacles beyond the agent's radius.
        mover_margin: metres of clearance kept from movers' predicted positions beyond both radii.
        lookahead: pure-pursuit carrot distance along the path, metres (scaled by the reach / 3 m).
        speeds: candidate speeds as fractions of the full reach per period, fastest first.
    """

    margin: float = 2.5
    mover_margin: float = 2.0
    lookahead: float = 8.0
    speeds: tuple[float, ...] = (1.0, 0.75, 0.5, 0.25, 0.0)
    parked_margin: float = 0.5
    """Metres kept beyond both discs from a mover predicted to stand still."""
    parked_range: float = 60.0
    """Metres: movers predicted to stand still closer than this are routed around like static obstacles."""
    body: bool = False
    """Check each candidate speed on the way the agent will really go and with its whole body: an aircraft's
    rollout follows its tracker's kinematics (``control.tracking.rollout_displacements``: it turns on the move
    and cannot pivot) and the circles at its nose and tail (``PlannerView.agent_circles``) must keep the margins
    too. Off: the agent's disc along the path, as if it could move sideways. Nothing changes for a walker, whose
    disc is its body."""

    keep_plan: bool = False
    """Keep ``planned`` after every ``act`` (``PrioritisedPlanner`` shares it with the agents after this one)."""

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode's obstacles."""
        self._graph: VisibilityGraph | None = None
        self.planned = np.zeros((0, 2))
        """(N, 2) where the last ``act`` means the agent to be over the next N periods (metres, world; with
        ``keep_plan``): the points along its path at the speed it chose, or (``body``, an aircraft) its kinematic
        rollout towards them."""
        self._graph_key: tuple | None = None

    def _parked(self, view: PlannerView) -> np.ndarray:
        """(n,) movers predicted to stand still over the horizon and near enough to matter."""
        future = view.mover_future
        if future.shape[0] == 0 or future.shape[1] == 0:
            return np.zeros(future.shape[0], dtype=bool)
        travel = np.hypot(*(future[:, -1] - view.movers.centers).T)
        near = np.hypot(*(view.movers.centers - view.agent_xy).T) < self.parked_range
        return (travel < 1.0) & near

    def path(self, view: PlannerView) -> np.ndarray:
        """Shortest path (m, 2) from the agent to the target around the statics and the parked movers."""
        parked = self._parked(view)
        fp = view.movers
        # rebuild the graph only when the statics or the parked movers changed (positions to 0.5 m, yaw to 0.1 rad)
        pose = np.concatenate([fp.centers[parked] * 2.0, fp.yaw[parked, None] * 10.0], axis=1)
        key = (id(view.statics), tuple(np.round(pose).astype(int).ravel().tolist()))
        if self._graph is None or key != self._graph_key:
            # pass a stopped vehicle closer than a static obstacle (``parked_margin`` beyond both discs, as the
            # speed check does): the grown blocker then rarely contains the agent and the path goes around it
            blockers = Footprints(
                fp.centers[parked],
                fp.half[parked],
                fp.yaw[parked],
                fp.radius[parked] + self.parked_margin + 0.25 - self.margin,
            )
            self._graph = VisibilityGraph(
                Footprints.concatenate([view.statics, blockers]), view.agent_radius + self.margin, view.bounds
            )
            self._graph_key = key
        try:
            return self._graph.shortest_path(view.agent_xy, view.target_xy)
        except NoPathError:
            pass
        # boxed in by parked movers: take the way round the statics alone and let the speed check wait
        try:
            return VisibilityGraph(view.statics, view.agent_radius + self.margin, view.bounds).shortest_path(
                view.agent_xy, view.target_xy
            )
        except NoPathError:
            return np.stack([view.agent_xy, view.target_xy])

    def act(self, view: PlannerView) -> np.ndarray:
        """Action (2,) in [-1, 1]^2: the displacement to ask for over the next period, as a fraction of reach.

        With ``keep_plan``, sets ``planned``: where the agent means to be over the movers' horizon."""
        path = self.path(view)
        scale = view.reach / 3.0
        carrot = _point_along(path, self.lookahead * max(scale, 0.25))
        to_carrot = carrot - view.agent_xy
        dist_goal = float(np.linalg.norm(view.target_xy - view.agent_xy))
        direction = to_carrot / max(float(np.linalg.norm(to_carrot)), 1e-9)
        fraction, _ = self._safe_speed(view, path)
        if self.keep_plan:
            self.planned = self._along(view, path, fraction, max(view.mover_future.shape[1], 1))
            if self.body and view.agent_limits is not None:  # where its kinematics take it along those points
                self.planned, _ = rollout_displacements(
                    view.agent_xy, view.agent_yaw, view.agent_speed, self.planned, view.period, view.agent_limits
                )
        # do not overshoot the goal
        step = min(fraction * view.reach, max(dist_goal - 0.5 * view.goal_radius, 0.0))
        return np.clip(direction * step / view.reach, -1.0, 1.0)

    def _clearance(self, view: PlannerView, ahead: np.ndarray) -> float:
        """Worst margin (metres) of a rollout ``ahead`` (N, 2) against the movers' predicted footprints.

        Each mover is its oriented footprint at its predicted position, turned to its direction of travel (its
        current heading while it stands). A moving mover must stay ``mover_margin`` beyond the footprint and the
        agent's disc; one predicted to stand still over the horizon (it is parked, dwelling or yielding) only
        ``parked_margin``. A mover already closer than that must not come closer. Positive means safe.
        """
        future = view.mover_future
        fp = view.movers
        parked = np.hypot(*(future[:, -1] - fp.centers).T) < 1.0
        margin = np.where(parked, self.parked_margin, self.mover_margin)  # (n,)
        headings = _headings(fp, future)
        if self.body:
            return self._body_clearance(view, ahead, margin, headings)
        need = view.agent_radius + margin
        floor = np.minimum(fp.distance(view.agent_xy)[0] - need, 0.0) - 0.05
        gap = _box_distance(ahead[None] - future, headings, fp.half, fp.radius) - need[:, None]
        now = fp.distance(ahead[0])[0] - need  # where they are during the first step
        return min(float((gap - floor[:, None]).min()), float((now - floor).min()))

    def _body_clearance(self, view: PlannerView, ahead: np.ndarray, margin: np.ndarray, headings: np.ndarray) -> float:
        """``_clearance`` for the agent's whole body (``body``): its disc and its end circles, on the rollout of
        its own kinematics towards the points ``ahead`` (an aircraft) or on those points (a walker)."""
        fp = view.movers
        if view.agent_limits is not None:
            pos, yaw = rollout_displacements(
                view.agent_xy, view.agent_yaw, view.agent_speed, ahead, view.period, view.agent_limits
            )
        else:
            pos, yaw = ahead, np.full(len(ahead), view.agent_yaw)
        circles = np.concatenate([[[0.0, 0.0, view.agent_radius]], view.agent_circles])
        worst = np.inf
        for x, y, r in circles:
            need = r + margin
            # where the circle is now, and along the rollout (its offset turned with the agent's heading)
            now_xy = view.agent_xy + agent_to_world(np.array([x, y]), view.agent_yaw)
            p = pos + np.stack([x * np.cos(yaw) - y * np.sin(yaw), x * np.sin(yaw) + y * np.cos(yaw)], axis=1)
            floor = np.minimum(fp.distance(now_xy)[0] - need, 0.0) - 0.05
            gap = _box_distance(p[None] - view.mover_future, headings, fp.half, fp.radius) - need[:, None]
            first = fp.distance(p[0])[0] - need  # where they are during the first step
            worst = min(worst, float((gap - floor[:, None]).min()), float((first - floor).min()))
        return worst

    def _safe_speed(self, view: PlannerView, path: np.ndarray) -> tuple[float, float]:
        """Fastest candidate speed whose rollout along ``path`` keeps clear of the movers, and its margin.

        If no candidate is clear, the one with the largest margin.
        """
        future = view.mover_future
        if future.shape[0] == 0 or future.shape[1] == 0:
            return self.speeds[0], np.inf
        n_steps = future.shape[1]
        best, best_clear = self.speeds[-1], -np.inf
        for frac in self.speeds:
            ahead = self._along(view, path, frac, n_steps)
            clear = self._clearance(view, ahead)
            if clear > 0:
                return frac, clear
            if clear > best_clear:
                best, best_clear = frac, clear
        return best, best_clear


    @staticmethod
    def _along(view: PlannerView, path: np.ndarray, fraction: float, n_steps: int) -> np.ndarray:
        """(n_steps, 2) the points reached along ``path`` at ``fraction`` of the reach per period, stopping
        halfway into the goal disc (as ``act`` does)."""
        seg = np.diff(path, axis=0)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        stop = max(cum[-1] - 0.5 * view.goal_radius, 0.0)
        s = np.minimum(fraction * view.reach * np.arange(1, n_steps + 1), stop)
        return np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=1)


class PrioritisedPlanner:
    """Prioritised planning for several agents (Erdmann and Lozano-Perez, 1987): every step the agents plan one
    after the other, each with its own ``ScriptedPlanner`` (whole body, ``body=True``), and each treats the plans
    of the agents before it as the future of those agents: where they mean to be over the horizon
    (``ScriptedPlanner.planned``), instead of the task's forecast of them. The agents after it, which have not
    planned yet, keep the task's forecast, as every mover does.

    The order is the agents' index (a fixed order: one that changed from step to step would let two agents each
    expect the other to give way); an agent that is done (None in ``act``'s ``views``) does not plan.

    Args:
        n_agents: how many agents plan.
        **scripted: ``ScriptedPlanner``'s arguments for every agent's planner (``body`` defaults to True).
    """

    def __init__(self, n_agents: int, **scripted: float | bool | tuple[float, ...]) -> None:
        scripted.setdefault("body", True)
        self._planners = [
            ScriptedPlanner(**scripted, keep_plan=True) for _ in range(n_agents)  # type: ignore[arg-type]
        ]

    def reset(self) -> None:
        """Forget the previous episode."""
        for planner in self._planners:
            planner.reset()

    def act(self, views: list[PlannerView | None], agent_rows: np.ndarray) -> list[np.ndarray | None]:
        """Every active agent's action (2,) in [-1, 1]^2 (world frame), None for an agent that is done.

        Args:
            views: agent i's full-knowledge view, its moving obstacles holding the other agents; None once it is
                done.
            agent_rows: (k, k) ``agent_rows[i, j]``: the row of agent j among the moving obstacles of agent i's
                view (-1 on the diagonal).
        """
        k = len(self._planners)
        if len(views) != k or np.shape(agent_rows) != (k, k):
            raise ValueError(f"{k} planners need {k} views and agent rows ({k}, {k}), got {len(views)} and "
                             f"{np.shape(agent_rows)}")
        active = [i for i in range(k) if views[i] is not None]
        order = active
        plans: dict[int, np.ndarray] = {}
        actions: list[np.ndarray | None] = [None] * k
        for i in order:
            view = views[i]
            if plans:
                future = view.mover_future.copy()
                for j, plan in plans.items():
                    future[agent_rows[i, j]] = plan[: future.shape[1]]
                view = dataclasses.replace(view, mover_future=future)
            actions[i] = self._planners[i].act(view)
            plans[i] = self._planners[i].planned
        return actions


def _point_along(path: np.ndarray, distance: float) -> np.ndarray:
    """The point ``distance`` metres along a polyline from its start (its end if shorter)."""
    return points_along(path, np.array([distance]))[0]


def _headings(movers: Footprints, future: np.ndarray, min_step: float = 0.3) -> np.ndarray:
    """(n, N) yaw of each mover at each predicted step: its direction of travel, its last yaw while it stands."""
    steps = np.diff(np.concatenate([movers.centers[:, None], future], axis=1), axis=1)  # (n, N, 2)
    yaw = np.arctan2(steps[..., 1], steps[..., 0])
    moving = np.hypot(steps[..., 0], steps[..., 1]) > min_step
    out = np.empty(future.shape[:2])
    last = movers.yaw.copy()
    for k in range(future.shape[1]):
        last = np.where(moving[:, k], yaw[:, k], last)
        out[:, k] = last
    return out


def _box_distance(rel: np.ndarray, yaw: np.ndarray, half: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Distance (n, N) from points at ``rel`` (n, N, 2) from each box centre to rounded boxes turned by ``yaw``.

    ``half`` (n, 2) and ``radius`` (n,) as in ``Footprints``; negative inside.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    lx = rel[..., 0] * c + rel[..., 1] * s
    ly = -rel[..., 0] * s + rel[..., 1] * c
    qx = np.abs(lx) - half[:, 0:1]
    qy = np.abs(ly) - half[:, 1:2]
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
    return outside + np.minimum(np.maximum(qx, qy), 0.0) - radius[:, None]


def _slow_near_goal(view: PlannerView, direction: np.ndarray, fraction: float = 1.0) -> np.ndarray:
    """Action along unit ``direction`` at ``fraction`` of the reach, shortened so as not to overshoot the goal."""
    dist_goal = float(np.linalg.norm(view.target_xy - view.agent_xy))
    step = min(fraction * view.reach, max(dist_goal - 0.5 * view.goal_radius, 0.0))
    return np.clip(direction * step / view.reach, -1.0, 1.0)


def _mover_discs(view: PlannerView) -> np.ndarray:
    """(n,) radius of the disc enclosing each mover's footprint, metres."""
    fp = view.movers
    return np.hypot(fp.half[:, 0], fp.half[:, 1]) + fp.radius


@dataclass
class APFPlanner:
    """Artificial potential field (Khatib, 1986): a unit pull towards the target plus the repulsion of every
    obstacle closer than ``influence``, followed at full speed along the resulting force.

    Repulsion of an obstacle at clearance rho (metres between the agent's disc and its footprint) is
    ``repulsion * (1/rho - 1/influence) / rho**2`` along the gradient of the distance, for the static obstacles,
    the surface's edges and each mover both where it is and where it is predicted ``mover_step`` steps ahead.
    A pure gradient follower: it stalls in the local minima in front of wide obstacles, the method's known
    weakness, which the evaluation is meant to show.
    """

    repulsion: float = 60.0
    """m^2 of repulsive gain (the pull towards the target is 1), at a reach of 3 m (scaled by (reach / 3 m)^2)."""
    influence: float = 10.0
    """Metres of clearance beyond which an obstacle does not repel, at a reach of 3 m (scaled by reach / 3 m)."""
    mover_step: int = 2
    """Which predicted step of each mover repels besides its present position."""
    min_clearance: float = 0.3
    """Clearances below this count as this (keeps the repulsion finite), metres at a reach of 3 m."""

    def reset(self) -> None:
        """The planner has no memory."""

    def _push(self, clearance: np.ndarray, away: np.ndarray, scale: float) -> np.ndarray:
        """Summed repulsion (2,) of obstacles at ``clearance`` (k,) in unit directions ``away`` (k, 2).

        Lengths scale with ``scale`` (the scene's reach over 3 m), so the field has the same shape on the square.
        """
        rho = np.maximum(clearance, self.min_clearance * scale)
        rho0 = self.influence * scale
        mag = np.where(rho < rho0, self.repulsion * scale * scale * (1.0 / rho - 1.0 / rho0) / rho**2, 0.0)
        return (mag[:, None] * away).sum(axis=0)

    @staticmethod
    def _gradient(fp: Footprints, p: np.ndarray, h: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
        """Distances (k,) from ``p`` to the footprints and their unit gradients (k, 2) (central differences)."""
        probes = p + np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
        d = fp.distance(probes)  # (5, k)
        g = np.stack([d[1] - d[2], d[3] - d[4]], axis=1) / (2 * h)
        return d[0], g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)

    def force(self, view: PlannerView) -> np.ndarray:
        """The net force (2,) on the agent: pull towards the target plus every repulsion."""
        p = view.agent_xy
        to_goal = view.target_xy - p
        force = to_goal / max(float(np.linalg.norm(to_goal)), 1e-9)
        r = view.agent_radius
        scale = view.reach / 3.0
        if len(view.statics):
            d, g = self._gradient(view.statics, p)
            force = force + self._push(d - r, g, scale)
        (xmin, ymin), (xmax, ymax) = view.bounds
        edge = np.array([p[0] - xmin, xmax - p[0], p[1] - ymin, ymax - p[1]]) - r
        force = force + self._push(edge, np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), scale)
        fp = view.movers
        if len(fp):
            d, g = self._gradient(fp, p)
            force = force + self._push(d - r, g, scale)
            if view.mover_future.shape[1] > 0:
                k = min(self.mover_step, view.mover_future.shape[1]) - 1
                ahead = Footprints(view.mover_future[:, k], fp.half, fp.yaw, fp.radius)
                d, g = self._gradient(ahead, p)
                force = force + self._push(d - r, g, scale)
        return force

    def act(self, view: PlannerView) -> np.ndarray:
        """Action (2,) in [-1, 1]^2: full reach along the force (less near the goal)."""
        f = self.force(view)
        return _slow_near_goal(view, f / max(float(np.linalg.norm(f)), 1e-9))


@dataclass
class AStarPlanner:
    """A* over a visibility graph of the static obstacles and the movers' predicted sweeps, replanned each step.

    Every step each mover becomes one rounded rectangle covering its footprint now and at the end of the
    predicted horizon (its sweep), the graph is rebuilt over those and the static obstacles (grown by the
    agent's radius and ``margin``), and the agent pursues the shortest path at full speed. With no path (boxed in
    by sweeps) it stands still for that step. It avoids movers only by going round where they will be, never
    by waiting: the difference from ``ScriptedPlanner``.
    """

    margin: float = 2.0
    """Metres kept from static obstacles beyond the agent's radius."""
    mover_margin: float = 1.0
    """Metres added to every mover's sweep (beyond ``margin``)."""
    sweep_steps: int = 6
    """Predicted steps each sweep covers (at most the predictor's horizon)."""
    lookahead: float = 8.0
    """Pure-pursuit carrot distance along the path, metres (scaled by reach / 3 m)."""

    def reset(self) -> None:
        """The planner has no memory."""

    def sweeps(self, view: PlannerView) -> Footprints:
        """One footprint per mover covering it now and ``sweep_steps`` predicted steps ahead."""
        fp = view.movers
        if len(fp) == 0:
            return Footprints.empty()
        if view.mover_future.shape[1] == 0:
            return fp.inflate(self.mover_margin)
        end = view.mover_future[:, min(self.sweep_steps, view.mover_future.shape[1]) - 1]
        delta = end - fp.centers
        length = np.hypot(delta[:, 0], delta[:, 1])
        moving = length > 0.5
        size = np.max(fp.half, axis=1)
        half = np.where(moving[:, None], np.stack([length / 2 + size, size], axis=1), fp.half)
        yaw = np.where(moving, np.arctan2(delta[:, 1], delta[:, 0]), fp.yaw)
        centers = np.where(moving[:, None], (fp.centers + end) / 2, fp.centers)
        return Footprints(centers, half, yaw, fp.radius + self.mover_margin)

    def path(self, view: PlannerView) -> np.ndarray | None:
        """Shortest path (m, 2) around the statics and the sweeps, or None if there is none."""
        obstacles = Footprints.concatenate([view.statics, self.sweeps(view)])
        graph = VisibilityGraph(obstacles, view.agent_radius + self.margin, view.bounds)
        try:
            return graph.shortest_path(view.agent_xy, view.target_xy)
        except NoPathError:
            return None

    def act(self, view: PlannerView) -> np.ndarray:
        """Action (2,) in [-1, 1]^2: pursue the replanned path at full reach; (0, 0) without a path."""
        path = self.path(view)
        if path is None:
            return np.zeros(2)
        carrot = _point_along(path, self.lookahead * max(view.reach / 3.0, 0.25))
        to_carrot = carrot - view.agent_xy
        return _slow_near_goal(view, to_carrot / max(float(np.linalg.norm(to_carrot)), 1e-9))


@dataclass
class MPCPlanner:
    """Model-predictive planner (CasADi + IPOPT): the agent's next ``horizon`` displacements optimised each step.

    The agent is a point moving by ``reach * u_k`` per decision (|u_k| <= 1, the action space). The cost tracks a
    reference that advances at full speed along the shortest path around the static obstacles (a visibility
    graph built once per episode), penalises effort changes, and adds squared-hinge penalties for (a) entering
    the disc of radius agent + mover + ``mover_margin`` around each mover's predicted position at the same step,
    (b) crossing the half-plane that separates the agent from each of the ``n_statics`` nearest static
    obstacles (linearised at the present position, kept ``margin`` away). The first displacement is the action;
    the rest warm-start the next solve. One NLP is built per (horizon, number of movers) and reused.
    """

    margin: float = 1.0
    """Metres kept from static obstacles beyond the agent's radius (the reference path keeps ``path_margin``)."""
    path_margin: float = 2.5
    """Metres the reference path keeps from static obstacles beyond the agent's radius."""
    mover_margin: float = 1.5
    """Metres kept between the agent's and each mover's enclosing discs."""
    n_statics: int = 6
    """Nearest static obstacles constrained by half-planes."""
    w_track: float = 1.0
    w_smooth: float = 2.0
    w_obstacle: float = 200.0
    max_iter: int = 60
    _solvers: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode's path and warm start."""
        self._graph: VisibilityGraph | None = None
        self._graph_key: int | None = None
        self._warm: np.ndarray | None = None
        self.last_status: str = ""

    def _solver(self, horizon: int, movers: int) -> ca.Function:
        key = (horizon, movers)
        if key not in self._solvers:
            u = ca.SX.sym("u", 2, horizon)
            p0 = ca.SX.sym("p0", 2)
            reach = ca.SX.sym("reach")
            ref = ca.SX.sym("ref", 2, horizon)
            u_prev = ca.SX.sym("u_prev", 2)
            mov = ca.SX.sym("mov", 2, horizon * movers)  # column k * movers + j: mover j at step k + 1
            safe = ca.SX.sym("safe", movers)
            nrm = ca.SX.sym("nrm", 2, self.n_statics)
            off = ca.SX.sym("off", self.n_statics)
            cost, g = 0, []
            p, last = p0, u_prev
            for k in range(horizon):
                p = p + reach * u[:, k]
                cost += self.w_track * ca.sumsqr(p - ref[:, k]) / (reach * reach)
                cost += self.w_smooth * ca.sumsqr(u[:, k] - last)
                last = u[:, k]
                for j in range(movers):
                    gap = ca.sqrt(ca.sumsqr(p - mov[:, k * movers + j]) + 1e-6)
                    cost += self.w_obstacle * ca.fmax(safe[j] - gap, 0) ** 2
                for i in range(self.n_statics):
                    cost += self.w_obstacle * ca.fmax(off[i] - ca.dot(nrm[:, i], p), 0) ** 2
                g.append(ca.sumsqr(u[:, k]))
            params = ca.vertcat(p0, reach, ca.vec(ref), u_prev, ca.vec(mov), safe, ca.vec(nrm), off)
            nlp = {"x": ca.vec(u), "p": params, "f": cost, "g": ca.vertcat(*g)}
            opts = {
                "ipopt.print_level": 0,
                "ipopt.sb": "yes",
                "print_time": False,
                "ipopt.max_iter": self.max_iter,
                "ipopt.tol": 1e-4,
                "ipopt.acceptable_tol": 1e-2,
                "ipopt.warm_start_init_point": "yes",
            }
            self._solvers[key] = ca.nlpsol("mpc_planner", "ipopt", nlp, opts)
        return self._solvers[key]

    def reference(self, view: PlannerView, horizon: int) -> np.ndarray:
        """(horizon, 2) points at full reach per step along the static shortest path (held at the goal)."""
        key = id(view.statics)
        if self._graph is None or key != self._graph_key:
            self._graph = VisibilityGraph(view.statics, view.agent_radius + self.path_margin, view.bounds)
            self._graph_key = key
        try:
            path = self._graph.shortest_path(view.agent_xy, view.target_xy)
        except NoPathError:
            path = np.stack([view.agent_xy, view.target_xy])
        seg = np.diff(path, axis=0)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        s = np.minimum(view.reach * np.arange(1, horizon + 1), cum[-1])
        return np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=1)

    def _half_planes(self, view: PlannerView) -> tuple[np.ndarray, np.ndarray]:
        """Normals (n_statics, 2) and offsets of the separating half-planes n.x >= offset of the nearest statics."""
        nrm = np.zeros((self.n_statics, 2))
        off = np.full(self.n_statics, -1e6)  # unused rows never bind
        if len(view.statics) == 0:
            return nrm, off
        p = view.agent_xy
        d, grad = APFPlanner._gradient(view.statics, p)
        order = np.argsort(d)[: self.n_statics]
        for row, i in enumerate(order):
            if d[i] <= 0.0:  # inside (should not happen): no usable separating plane
                continue
            closest = p - d[i] * grad[i]
            nrm[row] = grad[i]
            off[row] = float(grad[i] @ closest) + view.agent_radius + self.margin
        return nrm, off

    def act(self, view: PlannerView) -> np.ndarray:
        """Action (2,): the first displacement of the optimised plan (the reference's direction if IPOPT fails)."""
        future = view.mover_future
        horizon = future.shape[1] if future.shape[1] > 0 else 10
        n = len(view.movers)
        ref = self.reference(view, horizon)
        if future.shape[1] == 0:  # no prediction: the movers stay where they are
            future = np.repeat(view.movers.centers[:, None], horizon, axis=1)
        safe = view.agent_radius + _mover_discs(view) + self.mover_margin
        nrm, off = self._half_planes(view)
        u_prev = np.zeros(2) if self._warm is None else self._warm[:, 0]
        if self._warm is None:
            direction = ref - np.vstack([view.agent_xy, ref[:-1]])
            x0 = np.clip(direction / view.reach, -1.0, 1.0).T
        else:
            x0 = np.concatenate([self._warm[:, 1:], self._warm[:, -1:]], axis=1)
        params = np.concatenate(
            [
                view.agent_xy,
                [view.reach],
                ref.T.ravel(order="F"),
                u_prev,
                future.transpose(1, 0, 2).reshape(-1, 2).T.ravel(order="F"),
                safe,
                nrm.T.ravel(order="F"),
                off,
            ]
        )
        solver = self._solver(horizon, n)
        sol = solver(x0=x0.ravel(order="F"), p=params, lbx=-1.0, ubx=1.0, lbg=0.0, ubg=1.0)
        self.last_status = solver.stats()["return_status"]
        u = np.asarray(sol["x"]).reshape(2, horizon, order="F")
        if not np.all(np.isfinite(u)):
            self._warm = None
            step = ref[0] - view.agent_xy
            return _slow_near_goal(view, step / max(float(np.linalg.norm(step)), 1e-9))
        self._warm = u
        dist_goal = float(np.linalg.norm(view.target_xy - view.agent_xy))
        first = u[:, 0]
        length = float(np.linalg.norm(first)) * view.reach
        limit = max(dist_goal - 0.5 * view.goal_radius, 0.0)
        if length > limit:
            first = first * (limit / max(length, 1e-9))
        return np.clip(first, -1.0, 1.0)


__all__ = ["APFPlanner", "AStarPlanner", "MPCPlanner", "ScriptedPlanner"]
