"""Movers' behaviour rules and the scripted planner's clearance, numpy only (no MuJoCo)."""

import numpy as np

from deck_sim.behaviour import BehaviourParams, MoverBehaviour
from deck_sim.control.planners import ScriptedPlanner
from deck_sim.geometry import Footprints, VisibilityGraph
from deck_sim.types import PlannerView

PARAMS = BehaviourParams(
    speed_range=(2.0, 3.0),
    dwell_range=(3.0, 5.0),
    accel=1.0,
    decel=1.5,
    turn_rate=0.6,
    yield_distance=4.0,
    yield_to_agent=True,
)
SPOTS = np.array([[60.0, 0.0], [-60.0, 0.0], [0.0, 60.0], [0.0, -60.0]])
BOUNDS = np.array([[-100.0, -100.0], [100.0, 100.0]])


def _two_tractors(seed: int) -> tuple[MoverBehaviour, np.ndarray, np.ndarray]:
    behaviour = MoverBehaviour(
        spots=SPOTS,
        holonomic=np.zeros(2, dtype=bool),
        radii=np.array([1.0, 1.0]),
        params=PARAMS,
        fronts=np.array([2.0, 2.0]),
    )
    graph = VisibilityGraph(Footprints.empty(), 1.0, BOUNDS)
    # mover 0 faces +x with mover 1 standing crosswise right at its nose
    positions = np.array([[0.0, 0.0], [5.0, 0.0]])
    headings = np.array([0.0, np.pi / 2])
    behaviour.reset([graph, graph], positions, np.array([-1, -1]), np.random.default_rng(seed))
    return behaviour, positions, headings


def test_a_mover_blocked_at_its_nose_waits_then_heads_away_from_the_blocker():
    for seed in range(5):
        behaviour, positions, headings = _two_tractors(seed)
        agent = np.array([0.0, -90.0])  # far away
        first_aim = behaviour.aim[0].copy()
        t, dt = 0.0, 0.5
        while np.array_equal(behaviour.aim[0], first_aim) and t < 30.0:
            cmd = behaviour.command(t, dt, positions, headings, np.zeros(2), agent)
            assert behaviour.yielding[0] and cmd.speed[0] == 0.0
            t += dt
        # it gave up only after waiting ``stuck_time``, for a spot whose way leads away from the blocker
        assert PARAMS.stuck_time <= t < 30.0, f"seed {seed}: gave up after {t} s"
        aim = behaviour.aim[0] - positions[0]
        blocker = positions[1] - positions[0]
        assert aim @ blocker < 0.5 * np.linalg.norm(aim) * np.linalg.norm(blocker)
        # turned towards it (a tractor pivots on the spot), it drives off
        headings[0] = np.arctan2(aim[1], aim[0])
        cmd = behaviour.command(t, dt, positions, headings, np.zeros(2), agent)
        assert not behaviour.yielding[0] and cmd.speed[0] > 0.0


def test_a_slow_vehicle_may_turn_away_from_what_is_ahead_of_it():
    # the agent stands 6 m ahead of a stopped tractor whose aim lies behind it: the tractor does not wait
    behaviour, positions, headings = _two_tractors(0)
    positions = np.array([[0.0, 0.0], [0.0, 80.0]])
    behaviour.aim[0] = np.array([-60.0, 0.0])
    behaviour.waypoint[0] = behaviour.route_last[0]
    agent = np.array([6.0, 0.0])
    behaviour.command(0.0, 0.5, positions, headings, np.zeros(2), agent)
    assert not behaviour.yielding[0]
    # moving at speed along its heading, it does stop for the agent
    behaviour.command(0.5, 0.5, positions, headings, np.array([3.0, 0.0]), agent)
    assert behaviour.yielding[0]


# the aircraft agent as its collision geoms (``Aircraft.parts``): fuselage, wings, tail
AIRCRAFT_PARTS = np.array([[-0.05, 0.0, 8.25, 0.0, 0.9], [-1.6, 0.0, 2.2, 6.8, 0.0], [-7.4, 0.0, 1.2, 2.6, 0.0]])


def test_a_mover_yields_to_the_agent_by_its_shape_turned_to_its_heading():
    # a tractor drives along +x at 3 m/s; the aircraft agent's centre stands 8 m ahead and 9.5 m to the side:
    # beyond its 6.8 m wings, but its 9.15 m nose reaches into the tractor's lane when it points across it
    behaviour = MoverBehaviour(
        spots=SPOTS,
        holonomic=np.zeros(1, dtype=bool),
        radii=np.array([1.0]),
        params=PARAMS,
        fronts=np.array([2.0]),
        agent_radius=7.0,
        agent_parts=AIRCRAFT_PARTS,
    )
    graph = VisibilityGraph(Footprints.empty(), 1.0, BOUNDS)
    positions, headings, speeds = np.zeros((1, 2)), np.zeros(1), np.array([3.0])
    behaviour.reset([graph], positions, np.array([-1]), np.random.default_rng(0))
    behaviour.aim[0] = np.array([60.0, 0.0])
    agent = np.array([8.0, 9.5])
    behaviour.command(0.0, 0.5, positions, headings, speeds, agent, agent_yaw=-np.pi / 2)  # nose across the lane
    assert behaviour.yielding[0]
    behaviour.command(0.5, 0.5, positions, headings, speeds, agent, agent_yaw=0.0)  # parallel: wings 6.8 m wide
    assert not behaviour.yielding[0]
    # without the shape, the agent is a 7 m disc and the nose goes unseen
    disc = MoverBehaviour(
        spots=SPOTS,
        holonomic=np.zeros(1, dtype=bool),
        radii=np.array([1.0]),
        params=PARAMS,
        fronts=np.array([2.0]),
        agent_radius=7.0,
    )
    disc.reset([graph], positions, np.array([-1]), np.random.default_rng(0))
    disc.aim[0] = np.array([60.0, 0.0])
    disc.command(0.0, 0.5, positions, headings, speeds, agent, agent_yaw=-np.pi / 2)
    assert not disc.yielding[0]


def _view(mover_yaw: float, lateral: float) -> PlannerView:
    # an 18 m x 13 m aircraft standing at the origin; the agent (radius 7 m) passes it at ``lateral`` metres
    movers = Footprints(np.zeros((1, 2)), np.array([[9.0, 6.5]]), np.array([mover_yaw]), np.zeros(1))
    return PlannerView(
        agent_xy=np.array([-40.0, lateral]),
        agent_yaw=0.0,
        agent_speed=6.0,
        agent_radius=7.0,
        target_xy=np.array([40.0, lateral]),
        goal_radius=4.0,
        statics=Footprints.empty(),
        movers=movers,
        mover_future=np.zeros((1, 10, 2)),
        bounds=BOUNDS,
        reach=3.0,
        period=0.5,
    )


def test_the_planner_passes_a_standing_vehicle_by_its_footprint_not_its_circumcircle():
    planner = ScriptedPlanner()
    # 15 m from the centre line of a vehicle lying along the path: 1.5 m clear of its side, full speed
    alongside = planner.act(_view(0.0, 15.0))
    assert np.linalg.norm(alongside) > 0.99
    assert abs(alongside[1]) < 0.05  # straight on, no detour
    # the same vehicle turned across the path reaches 9 m towards it: the straight line is not clear any more
    path = planner.path(_view(np.pi / 2, 15.0))
    assert len(path) > 2 or np.max(np.abs(path[:, 1] - 15.0)) > 1.0
