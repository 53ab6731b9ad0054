"""Purposeful motion of the movers (paper's assumptions 1-3), commanded for all movers at once.

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
passed to ``reset``. Numpy and ``math`` only; the task feeds it measured positions, headings and speeds. The
per-step ``command_lists`` is the control step's hot path: with 5-13 movers numpy's cost per call outweighs its work,
so it runs on plain Python floats and looks only at the pairs of movers near enough to matter.
"""

from __future__ import annotations

import copy
import math
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
    agent_yield_braking: float = 0.0
    """m/s^2: above 0, the reach ahead for the agent grows by the mover's stopping distance at this braking,
    v^2 / (2 * agent_yield_braking), v its speed now capped at ``speed_range[1]``; 0 keeps it fixed."""
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
        # what each mover yields to: the other movers (pairs of discs and half-lengths) and, if enabled, the
        # agent (its parts turned to its heading, ``_agent_ahead``)
        # ahead: free distance + own half-length + the other's half-length; beside: both half-widths
        fronts = self.radii if self.fronts is None else np.asarray(self.fronts, dtype=float)
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
        # the stopping distance's share of the reach: v^2 * _agent_brake_gain, v capped at the fastest cruise
        b = self.params.agent_yield_braking
        self._agent_brake_gain = 0.5 / b if b > 0 else 0.0
        self._agent_brake_vmax = float(self.params.speed_range[1])
        brake_max = self._agent_brake_vmax**2 * self._agent_brake_gain
        near = np.hypot(self._agent_reach[:, 0] + brake_max + extent, self._agent_width[:, 0] + extent) + offset
        self._agent_near_sq = near * near
        # the hot path (``command_lists``) works on plain Python floats: its tables as nested lists
        self._yield_reach_l = self._yield_reach.tolist()
        self._contact_reach_l = self._contact_reach.tolist()
        self._yield_width_l = self._yield_width.tolist()
        self._agent_reach_l = self._agent_reach[:, 0].tolist()
        self._agent_width_l = self._agent_width[:, 0].tolist()
        self._agent_near_sq_l = self._agent_near_sq.tolist()
        # (1 cm beyond it, far beyond rounding: which movers the agent test is run for once it is run at all)
        self._agent_test_sq_l = ((near + 0.01) ** 2).tolist()
        self._agent_parts_l = self._agent_parts.tolist()
        self._holonomic_l = np.asarray(self.holonomic, dtype=bool).tolist()
        # pairs of movers that may be in each other's way: one lies within the longest reach ahead of the other and
        # within the width beside it, so closer than their hypotenuse (plus 1 cm, far beyond rounding); no other
        # pair is looked at (``_must_yield``)
        reach = np.hypot(np.maximum(self._yield_reach, self._contact_reach), self._yield_width) + 0.01
        self._pair_near_l = (reach * reach).tolist()
        self._pair_near_max = float(reach.max(initial=0.0))
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

    # -- the per-step command (the hot path: a few numpy calls over all movers, the rest plain Python floats) --
    def command(
        self, t: float, dt: float, positions: np.ndarray, headings: np.ndarray, speeds: np.ndarray,
        agent_xy: np.ndarray, agent_yaw: float | np.ndarray = 0.0,
    ) -> MoverCommands:
        """Desired motion of every mover for the control step starting at time ``t`` (seconds): ``command_lists``
        (same arguments) as arrays."""
        speed, yaw_rate, velocity = self.command_lists(t, dt, positions, headings, speeds, agent_xy, agent_yaw)
        return MoverCommands(self.cmd_speed, np.array(yaw_rate), np.array(velocity).reshape(len(speed), 2))

    def command_lists(
        self, t: float, dt: float, positions: np.ndarray, headings: np.ndarray, speeds: np.ndarray,
        agent_xy: np.ndarray, agent_yaw: float | np.ndarray = 0.0,
    ) -> tuple[list[float], list[float], list[tuple[float, float]]]:
        """Desired motion of every mover for the control step starting at time ``t`` (seconds), as plain lists
        (the task's per-step call): forward speed (n) m/s, turn rate (n) rad/s (zero for pedestrians) and
        world-frame velocity (n pairs) m/s.

        Args:
            dt: the control period, seconds.
            positions: (n, 2) metres; headings: (n,) radians; speeds: (n,) m/s, all measured now.
            agent_xy: (2,) the agent's position, metres; (k, 2) every agent's when several act at once (the
                movers yield to each, all of the same shape).
            agent_yaw: the agent's heading, radians (turns ``agent_parts``); (k,) with several agents.

        Only the transcendental functions run in numpy, one call over all movers each as in the vectorised
        version this replaced (so their results stay bit-identical); the rest is Python float arithmetic in the
        same order of operations, which gives the same commands bit for bit (``tests/test_behaviour.py``, golden
        closed loop) for finite inputs.
        """
        p = self.params
        n = len(self.radii)
        nan = math.nan
        to_aim = self.aim - positions
        aim_xy = to_aim.tolist()
        dist = [math.sqrt(x * x + y * y) for x, y in aim_xy]
        spd = speeds.tolist()
        mode = self.mode.tolist()
        driving = [m == DRIVING for m in mode]
        # events, rare: next waypoint, arrival, departure, stuck
        waypoint, route_last, dwell_until = self.waypoint.tolist(), self.route_last.tolist(), self.dwell_until.tolist()
        still, yielding, give_up = self.still_since.tolist(), self.yielding.tolist(), self.give_up.tolist()
        events = []
        stuck_time, arrive_tol, waypoint_tol = p.stuck_time, p.arrive_tolerance, p.waypoint_tolerance
        for i in range(n):
            drv, last_wp = driving[i], waypoint[i] >= route_last[i]
            if spd[i] > 0.2 or not drv:  # moving, or not driving
                still[i] = nan
            elif still[i] != still[i]:  # just stopped while driving
                still[i] = t
            stuck = (drv and t - still[i] > stuck_time and not yielding[i]) or give_up[i]
            if drv:
                event = dist[i] < arrive_tol and spd[i] < 0.6 if last_wp else dist[i] < waypoint_tol
            else:
                event = t >= dwell_until[i]
            if event or stuck:
                events.append((i, stuck, drv, last_wp))
        self.still_since[:] = still
        if events:
            for i, stuck, drv, last_wp in events:
                if stuck or (not drv and t >= self.dwell_until[i]):
                    if self.give_up[i]:
                        self.last_give_up[i] = t
                    away = self.blocked_by[i] if self.give_up_locked[i] else None
                    self._depart(i, positions[i], t, away_from=away)
                    self.agent_wait_since[i] = np.nan
                    self.give_up[i] = False
                elif not last_wp:
                    self.waypoint[i] += 1
                    self.aim[i] = self.routes[i][self.waypoint[i]]
                    self.rest_after_aim[i] = self.route_rest[i][self.waypoint[i]]
                else:
                    self._arrive(i, t)
            driving = [m == DRIVING for m in self.mode.tolist()]
            to_aim = self.aim - positions
            aim_xy = to_aim.tolist()
            dist = [math.sqrt(x * x + y * y) for x, y in aim_xy]

        yielding = self._must_yield(t, positions, headings, spd, aim_xy, dist, driving, agent_xy, agent_yaw)
        err_arr = (np.arctan2(to_aim[:, 1], to_aim[:, 0]) - headings + np.pi) % (2.0 * np.pi) - np.pi
        cos_err, err = np.cos(err_arr).tolist(), err_arr.tolist()
        cruise, rest, cmd_speed = self.cruise.tolist(), self.rest_after_aim.tolist(), self.cmd_speed.tolist()
        two_decel, half_dt = 2.0 * p.decel, 0.5 * dt
        accel_step, brake_step = p.accel * dt, p.decel * 2.0 * dt
        gain, turn, neg_turn, sqrt = p.heading_gain, p.turn_rate, -p.turn_rate, math.sqrt
        v_out: list[float] = []
        w_out: list[float] = []
        vel_out: list[tuple[float, float]] = []
        # (the builtin max(a, b) is ``b if b > a else a`` and min(a, b) is ``b if b < a else a``: written out, the
        # same floats, NaN and signed zeros included, without the calls)
        for d_i, r_i, s_i, c_i, cs_i, ce_i, e_i, yld, drv, hol, (ax, ay) in zip(
            dist, rest, spd, cruise, cmd_speed, cos_err, err, yielding, driving, self._holonomic_l, aim_xy, strict=True
        ):
            # speed profile: cruise, braking to a stop at the spot (planned half a step early)
            x = d_i + r_i - s_i * half_dt - 0.3
            v_stop = sqrt(two_decel * (0.0 if 0.0 > x else x))
            v_des = 0.0 if yld else (c_i if c_i < v_stop else v_stop) * drv
            # wheeled movers slow down while the heading error is large; pedestrians walk straight at the aim
            if hol:
                align = 1.0
            else:
                align = 0.0 if 0.0 > ce_i else ce_i
                align *= align
            v, bound = v_des * align, cs_i + accel_step
            v = v if v <= bound or v != v else bound  # np.minimum: a NaN in either gives NaN
            bound = cs_i - brake_step
            v = v if v >= bound or v != v else bound  # np.maximum
            if yld:
                v = 0.0  # yielding brakes at once, as hard as the drive allows
            if 0.0 > v:
                v = 0.0
            v_out.append(v)
            w = gain * e_i
            if turn < w:
                w = turn
            if neg_turn > w:
                w = neg_turn
            w_out.append(w * (drv and not hol))
            scale = v / (1e-6 if 1e-6 > d_i else d_i)
            vel_out.append((ax * scale, ay * scale))
        self.cmd_speed = np.array(v_out)
        return v_out, w_out, vel_out

    def _must_yield(
        self,
        t: float,
        positions: np.ndarray,
        headings: np.ndarray,
        speeds: list[float],
        to_aim: list[list[float]],
        dist_aim: list[float],
        driving: list[bool],
        agent_xy: np.ndarray,
        agent_yaw: float,
    ) -> list[bool]:
        """Whether each driving mover has something close ahead that it must stop for (n bools).

        Ahead means along the mover's heading; a vehicle slower than ``turn_speed`` (starting, or turning
        towards a new aim) only counts what is also ahead in the direction of its aim, so it can turn away
        from what blocks it; something right at its nose always counts. Sets ``yielding``, ``give_up``,
        ``give_up_locked``, ``blocked_by`` and the yield timers. Only the pairs of movers near enough to be in
        each other's way are looked at (``_pair_near_l``); all the others never are.
        """
        p = self.params
        n = len(self.radii)
        if p.yield_distance <= 0:
            return [False] * n
        nan = math.nan
        pos = positions.tolist()
        # vehicles look along their heading; pedestrians along the way they are going; slow vehicles also
        # look towards their aim
        fx, fy = np.cos(headings).tolist(), np.sin(headings).tolist()
        holonomic, turn_speed = self._holonomic_l, p.turn_speed
        slow = [False] * n
        aim_dir: list[tuple[float, float]] = [(0.0, 0.0)] * n  # where slow
        for i in range(n):
            d = dist_aim[i]
            if d > 1e-6:
                tx, ty = to_aim[i]
                if holonomic[i]:
                    fx[i], fy[i] = tx / d, ty / d
                if speeds[i] < turn_speed:
                    slow[i] = True
                    aim_dir[i] = (tx / d, ty / d)
        any_slow = any(slow)

        # pairs: (i, j) -> whether i yields to j (``movers``) and whether j is right at i's nose (``close``), for
        # the pairs near enough to matter (found by sweeping along x)
        reach_l, contact_l, width_l, near_l = (
            self._yield_reach_l,
            self._contact_reach_l,
            self._yield_width_l,
            self._pair_near_l,
        )
        xs = [q[0] for q in pos]
        order = sorted(range(n), key=xs.__getitem__)
        movers: dict[tuple[int, int], bool] = {}
        close_to: list[list[tuple[int, float]]] = [[] for _ in range(n)]  # i -> [(j, along)] right at its nose
        for k, a in enumerate(order):
            xa, ya = pos[a]
            for b in order[k + 1 :]:
                dx = xs[b] - xa
                if dx >= self._pair_near_max:
                    break
                dy = pos[b][1] - ya
                if dx * dx + dy * dy >= near_l[a][b]:
                    continue
                for i, j in ((a, b), (b, a)):
                    rx, ry = pos[j][0] - pos[i][0], pos[j][1] - pos[i][1]
                    along = rx * fx[i] + ry * fy[i]
                    beside = abs(rx * fy[i] - ry * fx[i]) < width_l[i][j]
                    yields = along > 0.0 and along < reach_l[i][j] and beside
                    close = along > 0.0 and along < contact_l[i][j] and beside
                    if close:
                        close_to[i].append((j, along))
                    if any_slow:
                        if yields and slow[i]:
                            ax, ay = aim_dir[i]
                            along_aim = rx * ax + ry * ay
                            yields = (
                                along_aim > 0.0 and along_aim < reach_l[i][j] and abs(rx * ay - ry * ax) < width_l[i][j]
                            )
                        yields = yields or close
                    if yields:
                        movers[(i, j)] = True
        # head on (each ahead of the other, facing each other): both wait and the higher-numbered one turns away;
        # in any other stand-off the lower index goes first
        by_mover, head_on_lower = [False] * n, [False] * n
        for i, j in movers:
            head_on = (j, i) in movers and fx[i] * fx[j] + fy[i] * fy[j] < -0.5
            if (j, i) not in movers or j < i or head_on:
                by_mover[i] = True
            if head_on and j < i:
                head_on_lower[i] = True

        # the agent (each agent, when several act at once), by its parts turned to its heading (only when it is
        # near some mover)
        for_agent = [False] * n
        if p.yield_to_agent:
            if np.ndim(agent_xy) == 1:
                agents = [(agent_xy, agent_yaw)]
            else:
                agents = list(zip(agent_xy, np.asarray(agent_yaw, dtype=float).tolist(), strict=True))
            test_sq, near_sq = self._agent_test_sq_l, self._agent_near_sq_l
            gain, vmax = self._agent_brake_gain, self._agent_brake_vmax
            for a_xy, a_yaw in agents:
                ax0, ay0 = float(a_xy[0]), float(a_xy[1])
                rel_sq = [(x - ax0) * (x - ax0) + (y - ay0) * (y - ay0) for x, y in pos]
                near = [i for i in range(n) if rel_sq[i] < test_sq[i] and not for_agent[i]]
                if not any(rel_sq[i] < near_sq[i] for i in near):
                    continue
                parts = self._agent_frame(a_xy, a_yaw)
                for i in near:
                    v = min(abs(speeds[i]), vmax)
                    extra = v * v * gain if gain else 0.0  # its stopping distance (0 with a fixed reach)
                    if self._agent_ahead(i, pos[i], fx[i], fy[i], parts, extra):
                        # a slow vehicle only counts the agent if it is also ahead towards its aim
                        for_agent[i] = not slow[i] or self._agent_ahead(i, pos[i], *aim_dir[i], parts, extra)

        ys, aws = self.yield_since.tolist(), self.agent_wait_since.tolist()
        last_give_up = self.last_give_up.tolist()
        yielding, give_up, locked = [False] * n, [False] * n, [False] * n
        for i in range(n):
            # a mover that waited too long for another mover goes anyway, but never into one right at its nose
            if not by_mover[i]:
                ys[i] = nan
            elif ys[i] != ys[i]:
                ys[i] = t
            at_nose = bool(close_to[i])
            waited = t - ys[i]
            yields = by_mover[i] and (waited <= p.max_yield_time or at_nose)
            drv = driving[i]
            yielding[i] = (yields or for_agent[i]) and drv
            # gridlock: one at its nose for longer than ``stuck_time`` -> head for a spot away from it (once per
            # ``max_yield_time``); a wheeled mover turns on the spot towards it and the one at its nose drops out
            # of view
            rested = not (t - last_give_up[i] < p.max_yield_time)
            if yields and at_nose and waited > p.stuck_time and drv and rested:
                locked[i] = True
                k = min(sorted(close_to[i]), key=lambda c: c[1])[0]  # the nearest ahead (lowest index on ties)
                self.blocked_by[i] = positions[k] - positions[i]
            # waiting for the agent: after ``max_yield_time`` the driver gives up and heads for another spot
            waits = for_agent[i] and drv
            if not waits:
                aws[i] = nan
            elif aws[i] != aws[i]:
                aws[i] = t
            # head on with another mover: the higher-numbered one heads for another spot (once per max_yield_time)
            give_up[i] = (waits and t - aws[i] > p.max_yield_time) or (head_on_lower[i] and drv and rested) or locked[i]
        self.yield_since[:] = ys
        self.agent_wait_since[:] = aws
        self.yielding = np.array(yielding, dtype=bool)
        self.give_up_locked = np.array(locked, dtype=bool)
        self.give_up = np.array(give_up, dtype=bool)
        return yielding

    def _agent_frame(self, agent_xy: np.ndarray, agent_yaw: float) -> tuple[list[tuple[float, ...]], float, float]:
        """The agent's parts in the world: per part its centre x, y, half-length, half-width and radius (metres),
        and the cosine and sine of its heading."""
        c, s = float(np.cos(agent_yaw)), float(np.sin(agent_yaw))
        x0, y0 = float(agent_xy[0]), float(agent_xy[1])
        parts = [(px * c - py * s + x0, px * s + py * c + y0, hx, hy, r) for px, py, hx, hy, r in self._agent_parts_l]
        return parts, c, s

    def _agent_ahead(
        self,
        i: int,
        position: list[float],
        dx: float,
        dy: float,
        agent: tuple[list[tuple[float, ...]], float, float],
        extra: float = 0.0,
    ) -> bool:
        """Whether any part of the agent lies in the corridor ahead of mover i (at ``position``) along (dx, dy).

        The corridor reaches ``agent_yield_distance`` plus ``extra`` metres (the mover's stopping distance, with
        ``agent_yield_braking``) beyond the mover's nose and the part's extent along that direction, and is as
        wide as both half-widths plus 1 m: a separating-axis test of the part's rounded box on the mover's two
        axes.
        """
        parts, c, s = agent
        ux = abs(dx * c + dy * s)  # the direction in the agent's frame
        uy = abs(dy * c - dx * s)
        x, y = position
        reach_i, width_i = self._agent_reach_l[i] + extra, self._agent_width_l[i]
        for cx, cy, hx, hy, r in parts:
            rx, ry = cx - x, cy - y
            along = rx * dx + ry * dy
            # the part's extent along the direction and across it
            if (
                along > 0.0
                and along < reach_i + (hx * ux + hy * uy + r)
                and abs(rx * dy - ry * dx) < width_i + (hx * uy + hy * ux + r)
            ):
                return True
        return False

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
