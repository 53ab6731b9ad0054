"""The MPC predictor's single-mover CasADi Function, built in named stages.

``build_function(settings)`` returns one symbolic Function (``casadi.SX``, common subexpressions
eliminated) that takes one mover's history and the step's shared inputs and returns its predicted positions,
its memory for the next step and an info vector. ``deck_sim.control.mpc_predictor`` maps it over all movers;
its module docstring describes the method. The stages of ``GraphBuilder.build``, in order:

1. ``declare_inputs``: the symbolic inputs.
2. ``frame``: every position relative to the mover's newest sample, m.
3. ``unpack_memory``: the previous step's memory split into its parts.
4. ``estimate_state``: the moving-horizon estimate (``deck_sim.control.mpc_estimation``).
5. ``standing_and_nearest``: whether the mover stands still, and at which spot.
6. ``update_belief``: the log-belief over the spots and "none".
7. ``choose_goal``: the likeliest hypothesis and how the rollout steers at it.
8. ``speeds``: cruise speed, braking deceleration and the speed under "none".
9. ``rollout_start``: the rollout's initial position, heading and speed.
10. ``predict_positions``: the wheeled and point rollouts (``deck_sim.control.mpc_rollout``), the mover's
    kind choosing between them.
11. ``assemble``: the Function with its named inputs and outputs.

Units are SI throughout: m, s, rad, m/s, m/s^2; log-beliefs are natural logarithms.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from deck_sim.control.mpc_estimation import Estimate, MovingHorizonEstimator
from deck_sim.control.mpc_rollout import Rollouts
from deck_sim.control.mpc_settings import N_ESTIMATE, MPCPredictorSettings
from deck_sim.control.mpc_symbolic import select, wrap_angle

FUNCTION_NAME = "deck_sim_mpc_predictor"
"""Name of the built Function (and of its generated C source and compiled library)."""


@dataclass(frozen=True)
class Inputs:
    """The Function's symbolic inputs (world coordinates, m) and the mover's kind."""

    history: ca.SX
    """(2, history) observed positions, oldest first, m."""
    spots: ca.SX
    """(2, max_spots) special spots, m."""
    spot_mask: ca.SX
    """(1, max_spots) 1 for a spot in use, 0 for unused capacity."""
    kind: ca.SX
    """1 for a pedestrian, 0 for a wheeled mover."""
    memory: ca.SX
    """(memory_size,) memory from the previous step (``MPCPredictorSettings.memory_size``)."""
    force_spot: ca.SX
    """Index of a spot to assume as the goal; -1: infer it."""
    self_index: ca.SX
    """This mover's column in ``others``."""
    others: ca.SX
    """(2, max_movers) newest positions of all movers, m."""
    others_velocity: ca.SX
    """(2, max_movers) their velocities, m/s."""
    others_mask: ca.SX
    """(1, max_movers) 1 for a mover present, 0 for unused capacity."""
    pedestrian: ca.SX
    """``kind > 0.5``."""


@dataclass(frozen=True)
class Frame:
    """The observations relative to the mover's newest sample."""

    now: ca.SX
    """(2,) newest observed position, world coordinates, m."""
    window: ca.SX
    """(2, estimation_window) the newest samples, newest first, relative to ``now``, m."""
    spots: ca.SX
    """(2, max_spots) the spots relative to ``now``, m."""
    others: ca.SX
    """(2, max_movers) all movers' newest positions relative to ``now``, m."""
    others_live: ca.SX
    """(1, max_movers) 1 for another mover present, 0 for this mover and unused capacity."""


@dataclass(frozen=True)
class Memory:
    """The memory vector's parts (see ``MPCPredictorSettings.memory_size``)."""

    estimate: ca.SX
    """(N_ESTIMATE,) previous estimate: position (world, m), heading rad, speed m/s, accel m/s^2, turn rate
    rad/s."""
    valid: ca.SX
    """1 once the estimate holds a previous step's result."""
    cruise_mean: ca.SX
    """Running mean of the cruising speed estimates, m/s."""
    cruise_count: ca.SX
    """Number of cruising samples behind that mean."""
    log_belief: ca.SX
    """(1, max_spots) log-belief of each spot."""
    log_none: ca.SX
    """Log-belief of "heading to no spot"."""
    excluded: ca.SX
    """(1, max_spots) 1 for the spot the mover last stopped at."""


@dataclass(frozen=True)
class Standing:
    """Whether the mover stands still, and where the spots are from it."""

    stopped: ca.SX
    """1 while the newest displacement(s) are within the standing-still threshold."""
    moving: ca.SX
    """``1 - stopped``."""
    distance: ca.SX
    """(1, max_spots) distance to each spot, m."""
    nearest: ca.SX
    """(1, max_spots) one-hot (several on ties) of the nearest spot in use."""
    at_spot: ca.SX
    """1 while stopped within ``at_spot_radius`` of a spot."""


@dataclass(frozen=True)
class Belief:
    """The updated belief, normalised so that the likeliest hypothesis has log-belief 0."""

    log_belief: ca.SX
    """(1, max_spots) log-belief of each spot, >= -1000."""
    log_none: ca.SX
    """Log-belief of "none", >= -1000."""
    excluded: ca.SX
    """(1, max_spots) 1 for the spot the mover last stopped at."""
    brake_lo: ca.SX
    """Lower end of the mover kind's braking deceleration range, m/s^2."""
    brake_hi: ca.SX
    """Upper end of it, m/s^2."""


@dataclass(frozen=True)
class Goal:
    """The chosen hypothesis and how the rollout approaches it."""

    best: ca.SX
    """Index of the chosen spot, -1 for "none"."""
    probability: ca.SX
    """Normalised probability of the likeliest hypothesis."""
    position: ca.SX
    """(2,) the chosen spot relative to the newest sample, m (0 under "none")."""
    steer: ca.SX
    """1 to steer at the spot with the model's full heading gain, 0 for the gentle detour gain."""
    has_goal: ca.SX
    """1 unless "none" is chosen."""


@dataclass(frozen=True)
class Speeds:
    """Speed targets and decelerations of the rollout, and the updated cruise memory."""

    cruise: ca.SX
    """Cruise speed towards the spot, m/s."""
    brake: ca.SX
    """Braking deceleration for the spot, m/s^2."""
    free: ca.SX
    """Speed target under "none", m/s."""
    brake_free: ca.SX
    """Braking limit under "none", m/s^2."""
    cruise_mean: ca.SX
    """Updated running mean cruise speed, m/s."""
    cruise_count: ca.SX
    """Updated number of cruising samples."""


@dataclass(frozen=True)
class RolloutStart:
    """Initial state and speed targets of the rollouts."""

    position: ca.SX
    """(2,) relative to the newest sample, m."""
    heading: ca.SX
    """rad."""
    speed: ca.SX
    """m/s."""
    cruise: ca.SX
    """Cruise speed towards the spot, m/s."""
    free: ca.SX
    """Speed target under "none", m/s."""


class GraphBuilder:
    """Builds the single-mover symbolic Function for one ``MPCPredictorSettings``; call ``build`` once."""

    def __init__(self, s: MPCPredictorSettings) -> None:
        self.s = s
        self.K = s.max_spots
        self.W = s.estimation_window

    def build(self) -> ca.Function:
        """The Function (history, spots, ..., others_mask) -> (prediction, memory_next, info); see the module
        docstring for its stages."""
        inp = self.declare_inputs()
        fr = self.frame(inp)
        mem = self.unpack_memory(inp.memory)
        est = self.estimate_state(fr, mem)
        st = self.standing_and_nearest(fr, inp.spot_mask)
        bel = self.update_belief(inp, fr, mem, est, st)
        goal = self.choose_goal(inp, fr, bel, est)
        spd = self.speeds(inp, mem, est, st, bel, goal)
        start = self.rollout_start(fr, est, spd)
        pred = self.predict_positions(inp, fr, st, bel, goal, spd, start)
        return self.assemble(inp, fr, est, st, bel, goal, spd, pred)

    # ----- inputs -----
    def declare_inputs(self) -> Inputs:
        """The Function's symbolic inputs."""
        s, K, H = self.s, self.K, self.s.history
        kind = ca.SX.sym("kind")
        return Inputs(
            history=ca.SX.sym("history", 2, H),
            spots=ca.SX.sym("spots", 2, K),
            spot_mask=ca.SX.sym("spot_mask", 1, K),
            kind=kind,
            memory=ca.SX.sym("memory", s.memory_size),
            force_spot=ca.SX.sym("force_spot"),
            self_index=ca.SX.sym("self_index"),
            others=ca.SX.sym("others", 2, s.max_movers),
            others_velocity=ca.SX.sym("others_velocity", 2, s.max_movers),
            others_mask=ca.SX.sym("others_mask", 1, s.max_movers),
            pedestrian=kind > 0.5,
        )

    def frame(self, inp: Inputs) -> Frame:
        """The newest position (m); the estimation window newest first, the spots and the other movers, all
        relative to it (m); which other movers are present."""
        s, H, W, K = self.s, self.s.history, self.W, self.K
        y_abs = inp.history
        others = inp.others - ca.repmat(y_abs[:, H - 1], 1, s.max_movers)
        others_live = inp.others_mask * ca.horzcat(*[inp.self_index != j for j in range(s.max_movers)])
        now = y_abs[:, H - 1]
        y = ca.horzcat(*[y_abs[:, H - 1 - j] - now for j in range(W)])
        spots = inp.spots - ca.repmat(now, 1, K)
        return Frame(now, y, spots, others, others_live)

    def unpack_memory(self, mem: ca.SX) -> Memory:
        """The memory vector split into its parts (layout: ``MPCPredictorSettings.memory_size``)."""
        K = self.K
        return Memory(
            estimate=mem[0:N_ESTIMATE],
            valid=mem[6],
            cruise_mean=mem[7],
            cruise_count=mem[8],
            log_belief=mem[10 : 10 + K].T,
            log_none=mem[10 + K],
            excluded=mem[11 + K : 11 + 2 * K].T,
        )

    def by_kind(self, inp: Inputs, wheeled: float, pedestrian: float) -> ca.SX:
        """``pedestrian`` for a pedestrian, else ``wheeled`` (a value of either mover model, in its units)."""
        return select(inp.pedestrian, pedestrian, wheeled)

    # ----- estimation -----
    def estimate_state(self, fr: Frame, mem: Memory) -> Estimate:
        """The mover's position (m, relative to the newest sample), heading (rad), speed (m/s), acceleration
        (m/s^2) and turn rate (rad/s) now, by the moving-horizon estimator warm-started from the memory."""
        return MovingHorizonEstimator(self.s).estimate(fr.window, fr.now, mem.estimate, mem.valid)

    # ----- intent -----
    def standing_and_nearest(self, fr: Frame, mask: ca.SX) -> Standing:
        """Whether the mover stands still, the distance to each spot (m) and whether it stands at the nearest.

        Standing still: the newest displacement (``stop_samples=2``: the newest two) is below the threshold
        (displacements of a standing mover are pure measurement noise: allow 3 sigma of a difference of two
        samples). One sample suffices: a fit across a hard stop sees a spurious acceleration, and a mover that
        has just stopped is likelier to stay.
        """
        s, y, spots = self.s, fr.window, fr.spots
        d1 = ca.norm_2(y[:, 0] - y[:, 1])
        d2 = ca.norm_2(y[:, 1] - y[:, 2])
        still_step = s.stop_speed * s.dt + 3.0 * np.sqrt(2.0) * s.position_noise
        stopped = select(s.stop_samples >= 2, ca.fmax(d1, d2), d1) < still_step
        dist = ca.sqrt(ca.sum1(spots * spots) + 1e-12)  # (1, K)
        big = 1e6
        dist_valid = dist + (1 - mask) * big
        dmin = ca.mmin(dist_valid)
        nearest = dist_valid <= dmin  # one-hot (ties: several)
        at_spot = stopped * (dmin < s.at_spot_radius)
        return Standing(stopped, 1 - stopped, dist, nearest, at_spot)

    def update_belief(self, inp: Inputs, fr: Frame, mem: Memory, est: Estimate, st: Standing) -> Belief:
        """The log-belief over the spots and "none" after this step's observation.

        While moving, the decayed log-belief gains each spot's log-likelihood (heading and braking terms) and
        "none" its constant; standing still keeps it; stopping at a spot resets it to uniform and excludes
        that spot."""
        s, mw, mp = self.s, self.s.wheeled, self.s.pedestrian
        spots, dist, mask = fr.spots, st.distance, inp.spot_mask
        th, v, w, decel = est.heading, est.speed, est.turn_rate, est.decel
        # Heading: lateral offset of each spot from the mover's (anticipated) line of travel, in metres near
        # the mover and in radians far away; spots behind it count as fully off the line.
        bearing = ca.atan2(spots[1, :], spots[0, :])
        err = wrap_angle(bearing - (th + w * s.turn_lookahead))
        lateral = select(ca.cos(err) > 0, dist * ca.sin(err), dist)
        ang_var = s.heading_sigma**2 + (s.speed_noise / ca.fmax(v, 0.05)) ** 2
        var = s.lateral_sigma**2 + ang_var * dist * dist
        # The floor (detours) only for spots ahead: a mover does not drive away from its spot.
        floor = s.heading_floor * ca.fmax(ca.cos(err), 0.0) + 1e-6
        ll_head = ca.log(floor + ca.exp(-(lateral * lateral) / (2 * var)))
        # Braking: a mover brakes for its spot once the deceleration needed to stop there (a_req) reaches its
        # own braking deceleration, drawn from [b_lo, b_hi]. Braking now: a_req should match the deceleration
        # seen. Not braking yet: P = fraction of braking decelerations still above a_req.
        b_lo = self.by_kind(inp, mw.brake_decel[0], mp.brake_decel[0])
        b_hi = self.by_kind(inp, mw.brake_decel[1], mp.brake_decel[1])
        a_req = v * v / (2 * ca.fmax(dist - s.stop_offset, 0.5))
        braking = 1.0 / (1.0 + ca.exp(-(decel - s.brake_threshold) / 0.1))
        sig_a = s.brake_sigma + s.brake_sigma_rel * a_req
        ll_brake = -((a_req - decel) ** 2) / (2 * sig_a * sig_a)
        frac = (b_hi + s.brake_margin - a_req) / (b_hi - b_lo + s.brake_margin)
        ll_cruise = ca.log(ca.fmin(ca.fmax(frac, s.brake_floor), 1.0))
        ll = ll_head + braking * ll_brake + (1 - braking) * ll_cruise
        moving = st.moving
        allowed = mask * (1 - mem.excluded)
        lb = select(moving, s.belief_decay * mem.log_belief + ll, mem.log_belief)
        lb_none = select(moving, s.belief_decay * mem.log_none + s.none_loglik, mem.log_none)
        lb = lb * allowed - (1 - allowed) * 1e3
        # Reset at a stop at a spot: uniform belief, exclude the spot it is at.
        lb = select(st.at_spot, -(1 - mask) * 1e3 - st.nearest * 1e3, lb)
        lb_none = select(st.at_spot, 0.0, lb_none)
        excl_new = select(st.at_spot, st.nearest, mem.excluded)
        top = ca.fmax(ca.mmax(lb), lb_none)
        lb = ca.fmax(lb - top, -1e3)
        lb_none = ca.fmax(lb_none - top, -1e3)
        return Belief(lb, lb_none, excl_new, b_lo, b_hi)

    def choose_goal(self, inp: Inputs, fr: Frame, bel: Belief, est: Estimate) -> Goal:
        """The likeliest hypothesis (or the forced spot), its position (m) and whether to steer at it fully."""
        s, K, spots = self.s, self.K, fr.spots
        lb, lb_none = bel.log_belief, bel.log_none
        th, v, w = est.heading, est.speed, est.turn_rate
        best = ca.SX(-1.0)
        best_l = lb_none
        for j in range(K):
            better = lb[j] > best_l
            best = select(better, j, best)
            best_l = select(better, lb[j], best_l)
        best = select(inp.force_spot >= 0, inp.force_spot, best)
        onehot = ca.horzcat(*[best == j for j in range(K)])
        goal = ca.mtimes(spots, onehot.T)
        # A mover heading away from the spot and not turning towards it may be on a detour leg around
        # something the predictor cannot see: steer at the spot only gently then.
        goal_err = wrap_angle(ca.atan2(goal[1], goal[0]) - th)
        turning_to = (w * goal_err > 0) * (ca.fabs(w) > s.cruise_turn_threshold)
        near = ca.norm_2(goal) < v * s.steer_time
        steer = ca.logic_or(
            ca.logic_or(turning_to, v < s.steer_speed), ca.logic_or(near, est.decel > s.brake_threshold)
        )
        p_best = ca.exp(best_l) / (ca.sum2(ca.exp(lb)) + ca.exp(lb_none))
        return Goal(best, p_best, goal, steer, best >= 0)

    # ----- speeds -----
    def speeds(self, inp: Inputs, mem: Memory, est: Estimate, st: Standing, bel: Belief, goal: Goal) -> Speeds:
        """Cruise speed (m/s), braking deceleration for the goal (m/s^2) and the speed and braking limit under
        "none"; updates the running mean of the cruising speed estimates (reset at a spot)."""
        s, mw, mp = self.s, self.s.wheeled, self.s.pedestrian
        v, acc, w, decel = est.speed, est.accel, est.turn_rate, est.decel
        b_lo, b_hi, at_spot = bel.brake_lo, bel.brake_hi, st.at_spot
        cruising = st.moving * (ca.fabs(acc) < s.cruise_accel_threshold) * (ca.fabs(w) < s.cruise_turn_threshold)
        cruising = cruising * (v > 0.5)
        n_new = select(at_spot, 0.0, mem.cruise_count + cruising)
        v_avg = mem.cruise_mean
        v_avg_new = select(cruising, v_avg + (v - v_avg) / ca.fmin(n_new, s.cruise_memory), v_avg)
        v_avg_new = select(at_spot, 0.0, v_avg_new)
        c_lo = self.by_kind(inp, mw.cruise_speed[0], mp.cruise_speed[0])
        c_hi = self.by_kind(inp, mw.cruise_speed[1], mp.cruise_speed[1])
        accelerating = acc > s.cruise_accel_threshold
        v_guess = select(accelerating, 0.5 * (ca.fmax(v, c_lo) + c_hi), v)
        v_cruise = select(n_new > 0.5, select(accelerating, ca.fmax(v_avg_new, v), v_avg_new), v_guess)
        v_cruise = ca.fmax(v_cruise, v)
        # Braking along its stopping profile for the goal: use the deceleration it shows (v^2 / 2d).
        d_goal = ca.norm_2(goal.position)
        b_seen = v * v / (2 * ca.fmax(d_goal - s.stop_offset, 0.1))
        b = select(decel > s.brake_threshold, ca.fmin(ca.fmax(b_seen, b_lo), b_hi), 0.5 * (b_lo + b_hi))
        v_free = select(accelerating, v_cruise, v)
        # Braking with no spot to explain it (yielding): keep braking at the rate seen, or hold the speed.
        brake_free = decel > s.brake_threshold
        if s.free_keeps_braking:
            v_free = select(brake_free, 0.0, v_free)
        b_free = select(brake_free, ca.fmin(decel, b_hi), b_hi)
        return Speeds(v_cruise, b, v_free, b_free, v_avg_new, n_new)

    # ----- rollouts -----
    def rollout_start(self, fr: Frame, est: Estimate, spd: Speeds) -> RolloutStart:
        """The rollouts' initial position (m, relative), heading (rad) and speed (m/s), and speed targets (m/s).

        The estimate; while the mover holds speed and heading, a straight-line fit over the last
        ``steady_line_window`` samples instead (fewer parameters, less noise: constant velocity is near-perfect
        there), whose speed then is also the cruise and "none" speed."""
        s, y = self.s, fr.window
        p0, th, v, acc, w = est.position, est.heading, est.speed, est.accel, est.turn_rate
        if s.steady_line_window < 2:
            return RolloutStart(p0, th, v, spd.cruise, spd.free)
        nl = s.steady_line_window
        tl = -np.arange(nl) * s.dt
        cl = (tl - tl.mean()) / np.sum((tl - tl.mean()) ** 2)
        v_line = ca.mtimes(y[:, 0:nl], ca.DM(cl))
        p_line = ca.sum2(y[:, 0:nl]) / nl - v_line * tl.mean()
        steady = (ca.fabs(acc) < s.cruise_accel_threshold) * (ca.fabs(w) < s.cruise_turn_threshold) * (v > 0.5)
        v_r = select(steady, ca.norm_2(v_line), v)
        return RolloutStart(
            position=select(steady, p_line, p0),
            heading=select(steady, ca.atan2(v_line[1], v_line[0]), th),
            speed=v_r,
            cruise=select(steady, v_r, spd.cruise),
            free=select(steady, v_r, spd.free),
        )

    def predict_positions(
        self, inp: Inputs, fr: Frame, st: Standing, bel: Belief, goal: Goal, spd: Speeds, start: RolloutStart
    ) -> ca.SX:
        """(2, horizon) predicted positions, world coordinates, m.

        One rollout per kind (unicycle for wheeled movers, point for pedestrians): to the chosen spot, or under
        "none" to a point far ahead on the current line; the mover's kind picks one. A mover standing still
        stays at the mean of its two newest samples."""
        s, y, now = self.s, fr.window, fr.now
        p_r, th_r, v_r = start.position, start.heading, start.speed
        has_goal, b = goal.has_goal, spd.brake
        far = p_r + 1e4 * ca.vertcat(ca.cos(th_r), ca.sin(th_r))
        r_goal = select(has_goal, goal.position, far)
        r_vc = select(has_goal, start.cruise, start.free)
        r_blim = select(has_goal, 2.0 * bel.brake_hi, spd.brake_free)
        r_steer = ca.logic_and(has_goal, goal.steer)
        vel0 = v_r * ca.vertcat(ca.cos(th_r), ca.sin(th_r))
        rollouts = Rollouts(s, fr.others, inp.others_velocity, fr.others_live)
        rw = rollouts.wheeled(p_r, th_r, v_r, r_goal, r_vc, b, r_blim, r_steer, s.wheeled)
        rp = rollouts.point(p_r, vel0, r_goal, r_vc, b, r_blim, r_steer, s.pedestrian)
        still = 0.5 * (y[:, 0] + y[:, 1])
        pred = []
        for k in range(s.horizon):
            pk = select(inp.pedestrian, rp[k], rw[k])
            pk = select(st.stopped, still, pk)
            pred.append(pk + now)
        return ca.horzcat(*pred)

    # ----- the Function -----
    def assemble(
        self,
        inp: Inputs,
        fr: Frame,
        est: Estimate,
        st: Standing,
        bel: Belief,
        goal: Goal,
        spd: Speeds,
        prediction: ca.SX,
    ) -> ca.Function:
        """The Function from the inputs to the prediction (2, horizon) m, the next memory (layout:
        ``MPCPredictorSettings.memory_size``) and the info vector (``N_INFO``)."""
        mem_new = ca.vertcat(
            est.position + fr.now,
            est.heading,
            est.speed,
            est.accel,
            est.turn_rate,
            1.0,
            spd.cruise_mean,
            spd.cruise_count,
            st.stopped,
            bel.log_belief.T,
            bel.log_none,
            bel.excluded.T,
        )
        info = ca.vertcat(
            goal.best, goal.probability, st.stopped, st.at_spot, est.speed, est.heading, est.accel, est.turn_rate
        )
        return ca.Function(
            FUNCTION_NAME,
            [
                inp.history,
                inp.spots,
                inp.spot_mask,
                inp.kind,
                inp.memory,
                inp.force_spot,
                inp.self_index,
                inp.others,
                inp.others_velocity,
                inp.others_mask,
            ],
            [prediction, mem_new, info],
            [
                "history",
                "spots",
                "spot_mask",
                "kind",
                "memory",
                "force_spot",
                "self_index",
                "others",
                "others_velocity",
                "others_mask",
            ],
            ["prediction", "memory_next", "info"],
            {"cse": True},
        )


def build_function(settings: MPCPredictorSettings) -> ca.Function:
    """The single-mover predictor Function for ``settings`` (see ``GraphBuilder.build``)."""
    return GraphBuilder(settings).build()
