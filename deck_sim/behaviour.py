"""Purposeful motion of the movers (paper's assumptions 1-3), vectorised over all movers.

Each mover picks a special spot, plans the shortest route around the static obstacles to it, drives the route
at a cruise speed drawn for this trip, brakes to a stop at the spot, dwells a random time, then picks another
spot (never the one it is at) and leaves at a new random speed. Movers brake for other movers close ahead of
them and, as an emergency stop, for the agent (``yield_to_agent``), judged by the agent's shape turned to its
heading (``agent_parts``: an aircraft's nose reaches past its wings). Rules that keep them from deadlocking or
shoving: when two wait on each other the lower-numbered one goes first, unless they meet head on, when both wait
and the higher-numbered one heads for another spot; a mover never drives into one right at its nose; one that
waited on the agent longer than ``max_yield_time`` heads for another spot.

The behaviour only *commands*: it returns desired velocities once per control step and the vehicles' actuators
produce the motion, so accelerations and turn rates are physical. Randomness comes only from the generator
passed to ``reset``. Numpy only; the task feeds it measured positions, headings and speeds.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from deck_sim.geometry import NoPathError, VisibilityGraph

DRIVING, DWELLING = 0, 1


@dataclass(frozen=True)
class BehaviourParams:
    """Limits and habits of the movers (from the scene's ``[movers]`` table)."""

    speed_range: tuple[float, float]
    """m/s, cruise speed drawn per trip."""
    dwell_range: tuple[float, float]
    """Seconds, dwell time drawn per stop."""
    accel: float
    """m/s^2, commanded acceleration limit."""
    decel: float
    """m/s^2, braking used to plan stops."""
    turn_rate: float
    """rad/s, largest commanded turn rate of wheeled movers."""
    yield_distance: float
    """Metres of free space a mover keeps ahead of it (0: never yields)."""
    yield_to_agent: bool
    """Whether the agent counts among the things a mover yields to."""
    agent_yield_distance: float = 6.0
    """Metres of free space a mover keeps ahead of it when the agent is there (an emergency stop: it brakes at
    once, as hard as its drive allows)."""
    arrive_tolerance: float = 1.0
    """Metres from the spot at which a slow mover counts as arrived."""
    waypoint_tolerance: float = 2.5
    """Metres from an intermediate waypoint at which the route's next waypoint becomes the aim."""
    heading_gain: float = 1.5
    """1/s, turn rate commanded per radian of heading error (wheeled)."""
    stuck_time: float = 12.0
    """Seconds of standing still while driving (not yielding) after which the mover picks another spot."""
    turn_speed: float = 1.0
    """m/s: below this a vehicle yields only to what is ahead both along its heading and towards its aim."""
    max_yield_time: float = 4.0
    """Seconds a mover yields to another mover before it goes anyway (never into one at its nose), or waits for
    the agent before it heads for another spot instead (no deadlocks)."""


@dataclass
class MoverCommands:
    """Desired motion of every mover for the next control step."""

    speed: np.ndarray
    """(n,) forward speed, m/s (wheeled) or walking speed (pedestrians)."""
    yaw_rate: np.ndarray
    """(n,) turn rate, rad/s (wheeled; zero for pedestrians)."""
    velocity: np.ndarray
    """(n, 2) world-frame velocity, m/s (what pedestrians use)."""


@dataclass
class MoverBehaviour:
    """Behaviour of n movers among fixed static obstacles.

    Args:
        spots: (k, 2) positions of the special spots, metres.
        holonomic: (n,) true for pedestrians (they walk in any direction).
        radii: (n,) radius of each mover's footprint disc, metres.
        params: the scene's limits.
    """

    spots: np.ndarray
    holonomic: np.ndarray
    radii: np.ndarray
    params: BehaviourParams
    fronts: np.ndarray | None = None
    """(n,) metres from each mover's centre to its nose (half-length); the radii when not given."""
    agent_radius: float = 0.0
    """Metres: radius of the disc that stands for the agent when ``agent_parts`` is not given."""
    agent_parts: np.ndarray | None = None
    """(k, 5) the agent's shape as rounded boxes in its own frame, one per collision geom: centre x, y,
    half-length, half-width, radius (metres; ``entities.planar_parts``). Movers yield to this shape turned to the
    agent's heading: an aircraft's nose reaches 9 m from its centre, its wings 7 m, so no disc fits it."""
    graphs: list[VisibilityGraph] = field(default_factory=list)

    def reset(
        self,
        graphs: list[VisibilityGraph],
        positions: np.ndarray,
        at_spot: np.ndarray,
        rng: np.random.Generator,
    ) -> None:
        """Start an episode: every mover leaves for a new spot at a new random speed.

        Args:
            graphs: one route graph per mover (movers of one kind may share one).
            positions: (n, 2) starting positions, metres.
            at_spot: (n,) index of the spot a mover starts at, or -1.
            rng: the episode's generator.
        """
        n = len(self.radii)
        self.graphs = graphs
        self._rng = rng
        self.mode = np.full(n, DRIVING)
        self.spot = np.asarray(at_spot, dtype=int).copy()  # spot being driven to, or dwelt at
        self.last_spot = np.asarray(at_spot, dtype=int).copy()
        self.cruise = np.zeros(n)
        self.dwell_until = np.zeros(n)
        self.cmd_speed = np.zeros(n)
        self.still_since = np.full(n, np.nan)
        self.yield_since = np.full(n, np.nan)
        self.yielding = np.zeros(n, dtype=bool)
        self.agent_wait_since = np.full(n, np.nan)
        self.give_up = np.zeros(n, dtype=bool)
        self.last_give_up = np.full(n, -np.inf)
        self.give_up_locked = np.zeros(n, dtype=bool)
        self.blocked_by = np.zeros((n, 2))  # direction to what blocks a gridlocked mover, metres
        self.routes: list[np.ndarray] = [np.zeros((0, 2))] * n
        self.route_rest = [np.zeros(0)] * n  # remaining route length after each waypoint
        self.waypoint = np.zeros(n, dtype=int)
        self.route_last = np.zeros(n, dtype=int)
        self._lower = np.arange(n)[None, :] < np.arange(n)[:, None]  # [i, j]: j < i
        # what each mover yields to: the other movers (pairs of discs and half-lengths) and, if enabled, the
        # agent (its parts turned to its heading, ``_agent_ahead``)
        # ahead: free distance + own half-length + the other's half-length; beside: both half-widths
        fronts = self.radii if self.fronts is None else np.asarray(self.fronts, dtype=float)
        self._fronts = fronts
        rsum = self.radii[:, None] + self.radii[None, :]
        fsum = fronts[:, None] + fronts[None, :]
        self._yield_reach = self.params.yield_distance + fsum
        self._yield_reach[np.arange(n), np.arange(n)] = -1.0  # never yield to oneself
        self._contact_reach = fsum + 2.0  # closer than this ahead: always wait
        self._yield_width = rsum + 0.5
        parts = self.agent_parts
        if parts is None:
            parts = np.array([[0.0, 0.0, 0.0, 0.0, self.agent_radius]])
        self._agent_parts = np.asarray(parts, dtype=float).reshape(-1, 5)
        self._agent_reach = (self.params.agent_yield_distance + fronts)[:, None]  # + the part's extent
        self._agent_width = (self.radii + 1.0)[:, None]  # + the part's extent
        # beyond this distance (squared) from a mover no part of the agent can lie in its corridor, whatever the
        # headings: the test is skipped while the agent is that far from every mover
        parts = self._agent_parts
        extent = float(np.max(np.hypot(parts[:, 2], parts[:, 3]) + parts[:, 4]))
        offset = float(np.max(np.hypot(parts[:, 0], parts[:, 1])))
        near = np.hypot(self._agent_reach[:, 0] + extent, self._agent_width[:, 0] + extent) + offset
        self._agent_near_sq = near * near
        self._any_holonomic = bool(np.any(self.holonomic))
        self._route_cache: dict[tuple[int, int, int], np.ndarray] = {}
        self.aim = np.asarray(positions, dtype=float).copy()
        self.rest_after_aim = np.zeros(n)
        for i in range(n):
            self._depart(i, positions[i], t=0.0)

    # -- events (Python per mover, rare) ---------------------------------------------------------------
    def _depart(self, i: int, position: np.ndarray, t: float, away_from: np.ndarray | None = None) -> None:
        """Mover i picks a new spot and speed and plans its route there.

        Args:
            away_from: (2,) direction (from the mover) of something blocking it: if given, only spots whose
                direction leads more than 60 degrees away from it are chosen (any spot if none does).
        """
        k = len(self.spots)
        choices = [s for s in range(k) if s != self.spot[i] and s != self.last_spot[i]] or [
            s for s in range(k) if s != self.spot[i]
        ]
        if away_from is not None:
            # the first leg of the route must lead more than 60 degrees away from the blocker
            away = []
            for s in choices:
                try:
                    leg = self.graphs[i].shortest_path(position, self.spots[s])[1] - position
                except NoPathError:
                    continue
                if leg @ away_from < 0.5 * np.linalg.norm(leg) * np.linalg.norm(away_from):
                    away.append(s)
            choices = away or choices
        self.last_spot[i] = self.spot[i]
        self.spot[i] = int(self._rng.choice(choices))
        lo, hi = self.params.speed_range
        self.cruise[i] = float(self._rng.uniform(lo, hi))
        self.mode[i] = DRIVING
        self.still_since[i] = np.nan
        self._plan(i, position)

    def _plan(self, i: int, position: np.ndarray) -> None:
        goal = self.spots[self.spot[i]]
        graph = self.graphs[i]
        # routes between spots do not change within an episode: plan each once per route graph
        frm = self.last_spot[i]
        key = (id(graph), int(frm), int(self.spot[i]))
        if frm >= 0 and np.linalg.norm(position - self.spots[frm]) < 3.0 and key in self._route_cache:
            route = self._route_cache[key]
        else:
            try:
                route = graph.shortest_path(position, goal)
            except NoPathError:
                route = np.stack([np.asarray(position, dtype=float), goal])
            if frm >= 0 and np.linalg.norm(position - self.spots[frm]) < 3.0:
                self._route_cache[key] = route
        route = route[1:]  # the first point is where the mover stands
        seg = np.linalg.norm(np.diff(route, axis=0), axis=1) if len(route) > 1 else np.zeros(0)
        rest = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]]) if len(seg) else np.zeros(1)
        self.routes[i] = route
        self.route_rest[i] = rest
        self.route_last[i] = len(route) - 1
        self.waypoint[i] = 0
        self.aim[i] = route[0]
        self.rest_after_aim[i] = rest[0]

    def _arrive(self, i: int, t: float) -> None:
        lo, hi = self.params.dwell_range
        self.mode[i] = DWELLING
        self.dwell_until[i] = t + float(self._rng.uniform(lo, hi))

    # -- the per-step command (vectorised; the hot path: keep the number of numpy calls small) -------------
    def command(
        self,
        t: float,
        dt: float,
        positions: np.ndarray,
        headings: np.ndarray,
        speeds: np.ndarray,
        agent_xy: np.ndarray,
        agent_yaw: float = 0.0,
    ) -> MoverCommands:
        """Desired motion of every mover for the control step starting at time ``t`` (seconds).

        Args:
            dt: the control period, seconds.
            positions: (n, 2) metres; headings: (n,) radians; speeds: (n,) m/s, all measured now.
            agent_xy: (2,) the agent's position, metres.
            agent_yaw: the agent's heading, radians (turns ``agent_parts``).
        """
        p = self.params
        driving = self.mode == DRIVING
        to_aim = self.aim - positions
        dist_aim = np.sqrt((to_aim * to_aim).sum(axis=1))
        last_wp = self.waypoint >= self.route_last
        # events, rare: next waypoint, arrival, departure, stuck
        events = (
            (driving & ~last_wp & (dist_aim < p.waypoint_tolerance))
            | (driving & last_wp & (dist_aim < p.arrive_tolerance) & (speeds < 0.6))
            | (~driving & (t >= self.dwell_until))
        )
        moving = speeds > 0.2
        self.still_since[moving | ~driving] = np.nan
        starting = ~moving & driving & np.isnan(self.still_since)
        self.still_since[starting] = t
        stuck = (driving & (t - self.still_since > p.stuck_time) & ~self.yielding) | self.give_up
        if events.any() or stuck.any():
            for i in np.flatnonzero(events | stuck):
                if stuck[i] or (not driving[i] and t >= self.dwell_until[i]):
                    if self.give_up[i]:
                        self.last_give_up[i] = t
                    away = self.blocked_by[i] if self.give_up_locked[i] else None
                    self._depart(i, positions[i], t, away_from=away)
                    self.agent_wait_since[i] = np.nan
                    self.give_up[i] = False
                elif not last_wp[i]:
                    self.waypoint[i] += 1
                    self.aim[i] = self.routes[i][self.waypoint[i]]
                    self.rest_after_aim[i] = self.route_rest[i][self.waypoint[i]]
                else:
                    self._arrive(i, t)
            driving = self.mode == DRIVING
            to_aim = self.aim - positions
            dist_aim = np.sqrt((to_aim * to_aim).sum(axis=1))

        # speed profile: cruise, braking to a stop at the spot (planned half a step early)
        remaining = dist_aim + self.rest_after_aim
        v_stop = np.sqrt(2.0 * p.decel * np.maximum(remaining - speeds * (0.5 * dt) - 0.3, 0.0))
        v_des = np.minimum(self.cruise, v_stop) * driving
        v_des[self._must_yield(t, positions, headings, speeds, to_aim, dist_aim, driving, agent_xy, agent_yaw)] = 0.0
        err = (np.arctan2(to_aim[:, 1], to_aim[:, 0]) - headings + np.pi) % (2.0 * np.pi) - np.pi
        # wheeled movers slow down while the heading error is large; pedestrians walk straight at the aim
        align = np.maximum(np.cos(err), 0.0)
        align *= align
        if self._any_holonomic:
            align[self.holonomic] = 1.0
        v_cmd = np.minimum(v_des * align, self.cmd_speed + p.accel * dt)
        np.maximum(v_cmd, self.cmd_speed - p.decel * 2.0 * dt, out=v_cmd)
        v_cmd[self.yielding] = 0.0  # yielding brakes at once, as hard as the drive allows
        np.maximum(v_cmd, 0.0, out=v_cmd)
        self.cmd_speed = v_cmd
        yaw_rate = np.minimum(p.heading_gain * err, p.turn_rate)
        np.maximum(yaw_rate, -p.turn_rate, out=yaw_rate)
        yaw_rate *= driving & ~self.holonomic
        velocity = to_aim * (v_cmd / np.maximum(dist_aim, 1e-6))[:, None]
        return MoverCommands(speed=v_cmd, yaw_rate=yaw_rate, velocity=velocity)

    def _must_yield(
        self,
        t: float,
        positions: np.ndarray,
        headings: np.ndarray,
        speeds: np.ndarray,
        to_aim: np.ndarray,
        dist_aim: np.ndarray,
        driving: np.ndarray,
        agent_xy: np.ndarray,
        agent_yaw: float,
    ) -> np.ndarray:
        """(n,) whether each driving mover has something close ahead that it must stop for.

        Ahead means along the mover's heading; a vehicle slower than ``turn_speed`` (starting, or turning
        towards a new aim) only counts what is also ahead in the direction of its aim, so it can turn away
        from what blocks it; something right at its nose always counts.
        """
        p = self.params
        n = len(self.radii)
        if p.yield_distance <= 0:
            return np.zeros(n, dtype=bool)
        # vehicles look along their heading; pedestrians along the way they are going
        fx, fy = np.cos(headings), np.sin(headings)
        if self._any_holonomic:
            hol = self.holonomic & (dist_aim > 1e-6)
            fx[hol] = to_aim[hol, 0] / dist_aim[hol]
            fy[hol] = to_aim[hol, 1] / dist_aim[hol]
        rx = positions[None, :, 0] - positions[:, 0:1]
        ry = positions[None, :, 1] - positions[:, 1:2]
        fx, fy = fx[:, None], fy[:, None]
        along = rx * fx + ry * fy
        lateral = np.abs(rx * fy - ry * fx)
        beside = lateral < self._yield_width
        movers = (along > 0.0) & (along < self._yield_reach) & beside
        close = (along > 0.0) & (along < self._contact_reach) & beside
        agent_parts = None
        if p.yield_to_agent:
            rel = positions - agent_xy
            if ((rel * rel).sum(axis=1) < self._agent_near_sq).any():
                agent_parts = self._agent_frame(agent_xy, agent_yaw)
        for_agent = self._agent_ahead(positions, fx, fy, agent_parts)
        slow = (speeds < p.turn_speed) & (dist_aim > 1e-6)
        if slow.any():
            ax = (to_aim[:, 0] / np.maximum(dist_aim, 1e-6))[:, None]
            ay = (to_aim[:, 1] / np.maximum(dist_aim, 1e-6))[:, None]
            along_aim = rx * ax + ry * ay
            towards = (
                (along_aim > 0.0) & (along_aim < self._yield_reach) & (np.abs(rx * ay - ry * ax) < self._yield_width)
            )
            movers &= ~slow[:, None] | towards
            movers |= close
            if (for_agent & slow).any():  # (the agent is rarely in anyone's way)
                for_agent &= ~slow | self._agent_ahead(positions, ax, ay, agent_parts)
        # head on (each ahead of the other, facing each other): both wait and the higher-numbered one turns away;
        # in any other stand-off the lower index goes first
        opposed = (fx * fx.T + fy * fy.T) < -0.5
        head_on = movers & movers.T & opposed
        movers &= ~movers.T | self._lower | head_on
        by_mover = movers.any(axis=1)
        # a mover that waited too long for another mover goes anyway, but never into one right at its nose
        self.yield_since[~by_mover] = np.nan
        self.yield_since[by_mover & np.isnan(self.yield_since)] = t
        at_nose = close.any(axis=1)
        waited = t - self.yield_since
        by_mover &= (waited <= p.max_yield_time) | at_nose
        self.yielding = (by_mover | for_agent) & driving
        # gridlock: one at its nose for longer than ``stuck_time`` -> head for a spot away from it (once per
        # ``max_yield_time``); a wheeled mover turns on the spot towards it and the one at its nose drops out of view
        rested = ~(t - self.last_give_up < p.max_yield_time)
        locked = by_mover & at_nose & (waited > p.stuck_time) & driving & rested
        if locked.any():
            for i in np.flatnonzero(locked):
                j = np.flatnonzero(close[i])
                k = j[np.argmin(along[i, j])]
                self.blocked_by[i] = positions[k] - positions[i]
        self.give_up_locked = locked
        # waiting for the agent: after ``max_yield_time`` the driver gives up and heads for another spot
        for_agent &= driving
        self.agent_wait_since[~for_agent] = np.nan
        self.agent_wait_since[for_agent & np.isnan(self.agent_wait_since)] = t
        self.give_up = for_agent & ((t - self.agent_wait_since) > p.max_yield_time)
        # head on with another mover: the higher-numbered one heads for another spot (once per max_yield_time)
        self.give_up |= ((head_on & self._lower).any(axis=1) & driving & rested) | locked
        return self.yielding

    def _agent_frame(self, agent_xy: np.ndarray, agent_yaw: float) -> tuple[np.ndarray, float, float]:
        """The agent's parts in the world: centres (k, 2), and the cosine and sine of its heading."""
        c, s = np.cos(agent_yaw), np.sin(agent_yaw)
        parts = self._agent_parts
        centres = np.stack([parts[:, 0] * c - parts[:, 1] * s, parts[:, 0] * s + parts[:, 1] * c], axis=1)
        return centres + agent_xy, c, s

    def _agent_ahead(
        self, positions: np.ndarray, dx: np.ndarray, dy: np.ndarray, agent: tuple[np.ndarray, float, float] | None
    ) -> np.ndarray:
        """(n,) whether any part of the agent lies in the corridor ahead of each mover along (dx, dy) (n, 1).

        The corridor reaches ``agent_yield_distance`` beyond the mover's nose and the part's extent along that
        direction, and is as wide as both half-widths plus 1 m: a separating-axis test of the part's rounded box
        on the mover's two axes.
        """
        if agent is None:
            return np.zeros(len(positions), dtype=bool)
        centres, c, s = agent
        parts = self._agent_parts
        rx = centres[None, :, 0] - positions[:, 0:1]  # (n, k)
        ry = centres[None, :, 1] - positions[:, 1:2]
        along = rx * dx + ry * dy
        lateral = np.abs(rx * dy - ry * dx)
        ux = np.abs(dx * c + dy * s)  # the direction in the agent's frame, (n, 1)
        uy = np.abs(dy * c - dx * s)
        reach = parts[:, 2] * ux + parts[:, 3] * uy + parts[:, 4]  # extent of each part along it, (n, k)
        width = parts[:, 2] * uy + parts[:, 3] * ux + parts[:, 4]  # and across it
        inside = (along > 0.0) & (along < self._agent_reach + reach) & (lateral < self._agent_width + width)
        return inside.any(axis=1)

    _STATE = (
        "mode",
        "spot",
        "last_spot",
        "cruise",
        "dwell_until",
        "cmd_speed",
        "still_since",
        "yield_since",
        "yielding",
        "agent_wait_since",
        "give_up",
        "last_give_up",
        "give_up_locked",
        "blocked_by",
        "routes",
        "route_rest",
        "route_last",
        "waypoint",
        "aim",
        "rest_after_aim",
    )

    def snapshot(self) -> dict:
        """A copy of the mutable state and of the random generator (for simulating ahead)."""
        state = {k: copy.deepcopy(getattr(self, k)) for k in self._STATE}
        state["rng"] = copy.deepcopy(self._rng)
        return state

    def restore(self, state: dict) -> None:
        """Return to a ``snapshot``."""
        for k in self._STATE:
            setattr(self, k, copy.deepcopy(state[k]))
        self._rng = copy.deepcopy(state["rng"])
