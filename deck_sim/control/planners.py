"""Planners that need no training, acting on full knowledge of the scene (``PlannerView``).

``ScriptedPlanner`` is how deck_sim knows a scene is solvable: it plans the shortest path around the static
obstacles (visibility graph, for a disc of the agent's radius plus a margin), follows it by pure pursuit, and
picks each step the fastest speed whose rollout along that path stays clear of every mover's predicted path
(the true future when the task runs the ``oracle`` predictor). It yields by slowing or stopping, never by
leaving its path. Numpy only (with ``deck_sim.geometry``); tested without MuJoCo.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deck_sim.geometry import Footprints, NoPathError, VisibilityGraph
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

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode's obstacles."""
        self._graph: VisibilityGraph | None = None
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
        """Action (2,) in [-1, 1]^2: the displacement to ask for over the next period, as a fraction of reach."""
        path = self.path(view)
        scale = view.reach / 3.0
        carrot = _point_along(path, self.lookahead * max(scale, 0.25))
        to_carrot = carrot - view.agent_xy
        dist_goal = float(np.linalg.norm(view.target_xy - view.agent_xy))
        direction = to_carrot / max(float(np.linalg.norm(to_carrot)), 1e-9)
        fraction, _ = self._safe_speed(view, path)
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
        need = view.agent_radius + np.where(parked, self.parked_margin, self.mover_margin)  # (n,)
        floor = np.minimum(fp.distance(view.agent_xy)[0] - need, 0.0) - 0.05
        gap = _box_distance(ahead[None] - future, _headings(fp, future), fp.half, fp.radius) - need[:, None]
        now = fp.distance(ahead[0])[0] - need  # where they are during the first step
        return min(float((gap - floor[:, None]).min()), float((now - floor).min()))

    def _safe_speed(self, view: PlannerView, path: np.ndarray) -> tuple[float, float]:
        """Fastest candidate speed whose rollout along ``path`` keeps clear of the movers, and its margin.

        If no candidate is clear, the one with the largest margin.
        """
        future = view.mover_future
        if future.shape[0] == 0 or future.shape[1] == 0:
            return self.speeds[0], np.inf
        n_steps = future.shape[1]
        seg = np.diff(path, axis=0)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        stop = max(cum[-1] - 0.5 * view.goal_radius, 0.0)  # as ``act``: halfway into the goal disc is enough
        best, best_clear = self.speeds[-1], -np.inf
        for frac in self.speeds:
            s = np.minimum(frac * view.reach * np.arange(1, n_steps + 1), stop)
            ahead = np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=1)
            clear = self._clearance(view, ahead)
            if clear > 0:
                return frac, clear
            if clear > best_clear:
                best, best_clear = frac, clear
        return best, best_clear


def _point_along(path: np.ndarray, distance: float) -> np.ndarray:
    """The point ``distance`` metres along a polyline from its start (its end if shorter)."""
    seg = np.diff(path, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    d = min(distance, cum[-1])
    return np.array([np.interp(d, cum, path[:, 0]), np.interp(d, cum, path[:, 1])])


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
