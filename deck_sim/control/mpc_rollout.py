"""The MPC predictor's rollouts: a mover's model driven to its goal under a goal-seeking control law.

Symbolic (``casadi.SX``): each rollout returns the mover's ``horizon`` future positions as expressions of
its initial state, goal and speed targets, for ``deck_sim.control.mpc_graph`` to assemble into the predictor's
Function. Positions are relative to the mover's newest observed sample, m; SI units throughout.
"""

from __future__ import annotations

import casadi as ca

from deck_sim.control.models import PointLimits, UnicycleLimits, holonomic_point, unicycle
from deck_sim.control.mpc_settings import MoverModel, MPCPredictorSettings
from deck_sim.control.mpc_symbolic import select, wrap_angle


class Rollouts:
    """Wheeled (unicycle) and pedestrian (holonomic point) rollouts that yield to the other movers.

    Args:
        s: The predictor's settings (horizon, dt, substeps, gains).
        others: (2, max_movers) the other movers' newest positions relative to this mover's newest sample, m.
        others_velocity: (2, max_movers) their velocities, m/s (extrapolated at constant velocity).
        others_live: (1, max_movers) 1 for another mover present, 0 for this mover and unused capacity.
    """

    def __init__(self, s: MPCPredictorSettings, others: ca.SX, others_velocity: ca.SX, others_live: ca.SX) -> None:
        self.s = s
        self.others = others
        self.others_vel = others_velocity
        self.others_live = others_live

    def speed_command(
        self, v: ca.SX, gap: ca.SX, v_cruise: ca.SX, b: ca.SX, b_lim: ca.SX, m: MoverModel
    ) -> tuple[ca.SX, ca.SX]:
        """(desired speed m/s, acceleration m/s^2) of a mover at speed ``v`` that cruises at ``v_cruise``
        and stops ``gap`` metres ahead braking at ``b``: track min(cruise, stopping profile) with the mover's
        time constant, braking no harder than ``b_lim``; once the deceleration needed to stop in the gap
        reaches ``b``, brake with exactly that deceleration."""
        room = gap - self.s.stop_offset
        v_des = ca.fmin(v_cruise, ca.sqrt(2.0 * b * ca.fmax(room, 0.0)))
        need = v * v / (2.0 * ca.fmax(room, 0.05))
        track = ca.fmax((v_des - v) / m.speed_time_constant, -b_lim)
        return v_des, select(need >= b, -ca.fmin(need, 2.0 * b), track)

    def blocked(self, p: ca.SX, direction: ca.SX, t: float, m: MoverModel) -> ca.SX:
        """1 where another mover (moving at its current velocity) is within ``m.yield_distance`` ahead of a
        mover at ``p`` going along the unit vector ``direction``, ``t`` seconds from now, and within
        ``m.yield_width`` of its line; else 0. Uses the other movers given to the constructor."""
        if m.yield_distance <= 0:
            return ca.SX(0)
        rel = self.others + t * self.others_vel - ca.repmat(p, 1, self.others.shape[1])
        along = direction[0] * rel[0, :] + direction[1] * rel[1, :]
        lateral = ca.fabs(direction[0] * rel[1, :] - direction[1] * rel[0, :])
        ahead = (along > 0.1) * (along < m.yield_distance) * (lateral < m.yield_width) * self.others_live
        return ca.mmax(ahead)

    def wheeled(
        self,
        p0: ca.SX,
        th0: ca.SX,
        v0: ca.SX,
        goal: ca.SX,
        v_cruise: ca.SX,
        b: ca.SX,
        b_lim: ca.SX,
        steer: ca.SX,
        m: MoverModel,
    ) -> list[ca.SX]:
        """Positions (horizon of (2,), m) of a unicycle starting at ``p0`` m, heading ``th0`` rad, speed ``v0``
        m/s, driving to ``goal`` m (see ``speed_command``).

        Steering (``steer``): turn at the bearing error times the model's heading gain, slowing as
        cos(error), and brake for the spot itself; otherwise turn at the detour gain and brake for the point
        abeam the spot. Stops while another mover is close ahead (``blocked``)."""
        s = self.s
        h = s.dt / s.rollout_substeps
        lim = UnicycleLimits(
            max_speed=m.max_speed,
            max_accel=m.max_accel,
            max_decel=2.0 * m.brake_decel[1],
            max_turn_rate=m.max_turn_rate,
        )
        f = unicycle(h, lim)
        gain = select(steer, m.heading_gain, s.detour_heading_gain)
        x = ca.vertcat(p0, th0, v0)
        out = []
        t = 0.0
        waited = ca.SX(0.0)
        for _ in range(s.horizon):
            for _ in range(s.rollout_substeps):
                d = goal - x[0:2]
                dist = ca.norm_2(d)
                err = wrap_angle(ca.atan2(d[1], d[0]) - x[2])
                err = select(dist < 0.5, 0.0, err)
                gap = select(steer, dist, dist * ca.cos(err))
                v_des, acc = self.speed_command(x[3], gap, v_cruise, b, b_lim, m)
                slow = select(steer, ca.fmax(ca.cos(err), 0.0), 1.0)
                acc = select(slow < 1.0, ca.fmin(acc, (v_des * slow - x[3]) / m.speed_time_constant), acc)
                stop = self.blocked(x[0:2], ca.vertcat(ca.cos(x[2]), ca.sin(x[2])), t, m) * (
                    waited < m.yield_time
                )
                waited = waited + h * stop
                acc = select(stop, ca.fmax(-x[3] / h, -2.0 * m.brake_decel[1]), acc)
                x = f(x, ca.vertcat(acc, gain * err))
                t += h
            out.append(x[0:2])
        return out

    def point(
        self,
        p0: ca.SX,
        vel0: ca.SX,
        goal: ca.SX,
        v_cruise: ca.SX,
        b: ca.SX,
        b_lim: ca.SX,
        steer: ca.SX,
        m: MoverModel,
    ) -> list[ca.SX]:
        """Positions (horizon of (2,), m) of a pedestrian (holonomic point) starting at ``p0`` m with velocity
        ``vel0`` m/s, walking to ``goal`` m.

        Its desired walking direction turns towards the goal (full or detour gain, within the turn-rate
        limit), its desired speed follows ``speed_command``, and the point tracks that desired velocity within
        its acceleration limit."""
        s = self.s
        h = s.dt / s.rollout_substeps
        f = holonomic_point(h, PointLimits(max_speed=m.max_speed, max_accel=2.0 * m.brake_decel[1]))
        gain = select(steer, m.heading_gain, s.detour_heading_gain)
        x = ca.vertcat(p0, vel0)
        psi = ca.atan2(vel0[1], vel0[0])
        out = []
        t = 0.0
        waited = ca.SX(0.0)
        for _ in range(s.horizon):
            for _ in range(s.rollout_substeps):
                d = goal - x[0:2]
                dist = ca.norm_2(d)
                err = wrap_angle(ca.atan2(d[1], d[0]) - psi)
                err = select(dist < 0.3, 0.0, err)
                psi = psi + h * ca.fmin(ca.fmax(gain * err, -m.max_turn_rate), m.max_turn_rate)
                gap = select(steer, dist, dist * ca.cos(err))
                speed = ca.norm_2(x[2:4])
                _, acc = self.speed_command(speed, gap, v_cruise, b, b_lim, m)
                heading = ca.vertcat(ca.cos(psi), ca.sin(psi))
                stop = self.blocked(x[0:2], heading, t, m) * (waited < m.yield_time)
                waited = waited + h * stop
                acc = select(stop, -speed / h, acc)
                x = f(x, (ca.fmax(speed + acc * h, 0.0) * heading - x[2:4]) / h)
                t += h
            out.append(x[0:2])
        return out
