"""Physics of the models and the task: no warnings, the aircraft drives and turns, movers go, dwell and leave,
collisions end the episode, bad actions are refused."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

import deck_sim
from deck_sim.behaviour import DRIVING, DWELLING
from deck_sim.tasks.navigate import InvalidActionError

ASSETS = Path(deck_sim.__file__).parent / "assets"
SCENE_FILES = sorted(ASSETS.glob("scene_*.xml"))


def _yaw(quat: np.ndarray) -> float:
    w, x, y, z = quat
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


@pytest.mark.parametrize("path", SCENE_FILES, ids=[p.stem for p in SCENE_FILES])
def test_every_scene_file_steps_two_seconds_with_random_controls_without_warnings(path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    rng = np.random.default_rng(0)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    for _ in range(int(2.0 / model.opt.timestep)):
        if model.nu:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
    assert [int(w.number) for w in data.warning] == [0] * len(data.warning)
    assert np.all(np.isfinite(data.qpos))


def _aircraft():
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_aircraft.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    model.opt.timestep = deck_sim.load_scene("deck1").episode.physics_timestep
    return model, data


def test_aircraft_drives_a_straight_line():
    model, data = _aircraft()
    data.ctrl[:] = [0.0, 0.3, 0.0, 0.0]  # 9 kN of thrust, no steer, no brakes
    mujoco.mj_step(model, data, nstep=int(10.0 / model.opt.timestep))
    assert data.qpos[0] > 20.0  # it rolled forward
    assert abs(data.qpos[1]) < 0.01 and abs(_yaw(data.qpos[3:7])) < 1e-3  # dead straight
    assert abs(data.qpos[2] - 1.8) < 0.01  # on its wheels


def test_aircraft_turns_by_its_nose_wheel_at_the_kinematic_rate():
    model, data = _aircraft()
    data.ctrl[:] = [0.0, 0.3, 0.0, 0.0]
    mujoco.mj_step(model, data, nstep=int(6.0 / model.opt.timestep))
    data.ctrl[:] = [0.3, 0.1, 0.0, 0.0]  # 0.3 rad nose-wheel steer
    mujoco.mj_step(model, data, nstep=int(5.0 / model.opt.timestep))
    speed = np.hypot(*data.qvel[:2])
    kinematic = speed * np.tan(data.qpos[7]) / 5.4  # bicycle model, wheelbase 5.4 m
    assert data.qvel[5] > 0.1  # turning left
    assert data.qvel[5] == pytest.approx(kinematic, rel=0.03)


@pytest.mark.parametrize("start, goal", [(0.9, -0.9), (0.0, 1.2), (1.2, -1.2)])
def test_the_nose_wheel_swings_lock_to_lock_at_a_standstill_and_settles(start, goal):
    # a large steer step saturates the servo's torque; with too little steering inertia the clamped servo flipped
    # sign every physics step (27 rad/s chatter, the wheel stuck 0.2-0.8 rad off) and the aircraft could not turn
    model, data = _aircraft()
    steer = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "nose_steer")]
    data.ctrl[:] = [start, 0.0, 1.0, 1.0]
    mujoco.mj_step(model, data, nstep=int(3.0 / model.opt.timestep))
    data.ctrl[:] = [goal, 0.2, 0.0, 0.0]
    mujoco.mj_step(model, data, nstep=int(2.0 / model.opt.timestep))
    speeds = []
    for _ in range(8):
        mujoco.mj_step(model, data)
        speeds.append(abs(data.qvel[steer]))
    assert data.actuator_length[0] == pytest.approx(goal, abs=0.02)
    assert max(speeds) < 0.05
    speed = np.hypot(*data.qvel[:2])
    assert speed > 0.1 and np.sign(data.qvel[5]) == np.sign(goal)  # rolling and turning the way it is steered


def test_the_tracker_turns_the_aircraft_round_from_rest():
    from deck_sim.control.tracking import AircraftLimits, track_displacement

    model, data = _aircraft()
    limits = AircraftLimits(mass=float(model.body_subtreemass[1]))
    for goal in (np.pi / 2, np.radians(175)):
        mujoco.mj_resetDataKeyframe(model, data, 0)
        nsub = int(round(0.5 / model.opt.timestep))
        for _ in range(24):  # 12 s
            yaw = _yaw(data.qpos[3:7])
            speed = data.qvel[0] * np.cos(yaw) + data.qvel[1] * np.sin(yaw)
            cmd = track_displacement(3 * np.cos(goal), 3 * np.sin(goal), yaw, speed, 0.5, limits)
            data.ctrl[:] = [cmd.steer, cmd.thrust, cmd.brake, cmd.brake]
            mujoco.mj_step(model, data, nstep=nsub)
        error = (goal - _yaw(data.qpos[3:7]) + np.pi) % (2 * np.pi) - np.pi
        assert abs(error) < np.radians(10), f"asked for {np.degrees(goal):.0f} deg, off by {np.degrees(error):.0f}"


def test_aircraft_brakes_to_a_stop():
    model, data = _aircraft()
    data.ctrl[:] = [0.0, 0.5, 0.0, 0.0]
    mujoco.mj_step(model, data, nstep=int(6.0 / model.opt.timestep))
    assert np.hypot(*data.qvel[:2]) > 3.0
    data.ctrl[:] = [0.0, 0.0, 1.0, 1.0]
    mujoco.mj_step(model, data, nstep=int(6.0 / model.opt.timestep))
    assert np.hypot(*data.qvel[:2]) < 0.05


def test_tractor_drives_and_turns_on_its_wheels():
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_tractor.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    data.ctrl[:] = [8.0, 8.0]  # wheel speeds, rad/s: 3.2 m/s
    mujoco.mj_step(model, data, nstep=int(5.0 / model.opt.timestep))
    assert data.qvel[0] == pytest.approx(3.2, rel=0.03)
    data.ctrl[:] = [5.0, 7.0]
    mujoco.mj_step(model, data, nstep=int(8.0 / model.opt.timestep))
    assert data.qvel[5] == pytest.approx(0.5, rel=0.12)  # (7 - 5) rad/s * 0.4 m / 1.6 m track


def test_a_mover_reaches_a_spot_dwells_and_leaves():
    env = deck_sim.load("deck1", seed=5, movers__tractors=1, movers__aircraft=0, static__slotted=15)
    env.reset()
    task = env.task
    behaviour = task._behaviour
    modes, positions, spots = [], [], []
    for _ in range(400):
        env.step(np.zeros(2))
        modes.append(int(behaviour.mode[0]))
        positions.append(task.last_info["mover_positions"][0].copy())
        spots.append(int(behaviour.spot[0]))
        if DWELLING in modes and modes[-12:] == [DWELLING] + [DRIVING] * 11:
            break
    modes = np.array(modes)
    first_dwell = int(np.argmax(modes == DWELLING))
    assert modes[0] == DRIVING and first_dwell > 0, "the mover never arrived"
    spot_xy = task._spot_xy[spots[first_dwell]]
    assert np.linalg.norm(positions[first_dwell] - spot_xy) < 1.5  # stopped at its spot
    dwell_end = first_dwell + int(np.argmax(modes[first_dwell:] == DRIVING))
    assert dwell_end > first_dwell + 4  # it dwelt at least 3 s (6 steps of 0.5 s, minus arrival rounding)
    assert np.ptp(np.array(positions[first_dwell + 1 : dwell_end]), axis=0).max() < 0.3  # standing still
    assert spots[dwell_end] != spots[first_dwell]  # left for another spot
    assert np.linalg.norm(positions[-1] - spot_xy) > 2.0  # and is on its way (5 s after leaving)


def test_driving_into_a_parked_aircraft_ends_the_episode_with_the_collision_reward():
    env = deck_sim.load("deck1", seed=3, movers__tractors=0, movers__aircraft=0, movers__spots=[])
    task = env.task
    for _ in range(20):
        ts = env.reset()
        view = task.planner_view()
        # the nearest parked aircraft (not the island): steer straight at it
        parked = view.statics.centers[:-1]
        target = parked[np.argmin(np.linalg.norm(parked - view.agent_xy, axis=1))]
        if np.linalg.norm(target - view.agent_xy) < 60:
            break
    for _ in range(200):
        direction = target - task.last_info["position"]
        ts = env.step(direction / np.linalg.norm(direction))
        if ts.last():
            break
    info = task.last_info
    assert info["collision"] is not None and info["collision"].startswith("parked_aircraft")
    assert ts.last() and ts.discount == 0.0
    assert info["reward_terms"]["r3"] == task.spec.reward.collision
    assert ts.reward == pytest.approx(info["reward_terms"]["total"])


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf], [1.5, 0.0], [0.0, -2.0]])
def test_nan_infinite_or_out_of_range_actions_raise_a_clear_error(envs, bad):
    env = envs["deck1"]
    env.reset()
    with pytest.raises(InvalidActionError, match="finite|\\[-1, 1\\]"):
        env.step(np.array(bad))
    with pytest.raises(InvalidActionError, match="shape"):
        env.step(np.zeros(3))


def test_physics_divergence_ends_the_episode_cleanly_and_is_flagged(envs):
    env = envs["deck1"]
    env.reset()
    env.step(np.array([0.5, 0.0]))
    env.physics.data.qvel[:] = 1e12  # an impossible state: MuJoCo warns and resets
    ts = env.step(np.array([0.5, 0.0]))
    assert ts.last()
    assert env.task.last_info["diverged"]
    assert ts.discount == 0.0
    ts = env.reset()  # and the environment carries on
    assert np.all(np.isfinite(ts.observation["position"]))


def test_the_pedestrian_agent_walks_where_it_is_asked_whatever_its_start_heading():
    env = deck_sim.load(
        "square",
        seed=1000,
        movers__pedestrians=0,
        movers__spawn_near_agent=0,
        static__scattered=0,
        static__slotted=0,
    )
    for _ in range(3):
        env.reset()
        start = env.task.last_info["position"].copy()
        for _ in range(6):
            env.step(np.array([1.0, 0.0]))  # east at the full reach
        moved = env.task.last_info["position"] - start
        assert moved[0] > 3.0 and abs(moved[1]) < 0.05


def test_movers_meeting_nose_to_nose_do_not_push_each_other():
    """Two tractors driving at each other: neither is pushed backwards; one gives way and goes elsewhere."""
    env = deck_sim.load("deck1", seed=8, movers__tractors=2, movers__aircraft=0, movers__yield_to_agent=False)
    env.reset()
    task = env.task
    behaviour = task._behaviour
    # send both tractors along the same line towards each other, 40 m apart, on open deck
    start = np.array([[190.0, 2.0], [230.0, 2.0]])
    physics = env.physics
    for i, (mover, yaw) in enumerate(zip(task.movers, (0.0, np.pi), strict=True)):
        mover.set_pose(physics, np.array([*start[i], 0.0]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]))
        behaviour.routes[i] = start[1 - i][None].copy()
        behaviour.route_rest[i] = np.zeros(1)
        behaviour.route_last[i] = 0
        behaviour.waypoint[i] = 0
        behaviour.aim[i] = start[1 - i]
        behaviour.cruise[i] = 3.0
    physics.forward()
    previous = start.copy()
    backwards, closest = 0.0, np.inf
    for _ in range(80):
        if env.step(np.zeros(2)).last():
            break
        pos, yaw = task.last_info["mover_positions"], task.last_info["mover_yaw"]
        step = pos - previous
        along = step[:, 0] * np.cos(yaw) + step[:, 1] * np.sin(yaw)
        backwards += float(np.clip(-along, 0.0, None).sum())
        closest = min(closest, float(np.linalg.norm(pos[0] - pos[1])))
        previous = pos.copy()
    # nobody is shoved backwards: before the fix one pushed the other at 0.4 m/s for over 30 s (more than 10 m);
    # waiting tractors that pivot towards a new aim twitch their centres by centimetres a step
    assert backwards < 3.0
    assert closest > 4.3  # 4 m of noses (two 2 m half-lengths) and never touching


def test_controller_constants_are_read_from_the_compiled_models(envs):
    task = envs["deck2"].task
    physics = envs["deck2"].physics
    limits = task.agent.physical_limits(physics)
    assert limits["wheelbase"] == pytest.approx(5.4)  # nose axle at +4.8 m, main axle at -0.6 m
    assert limits["max_thrust"] == 30000.0 and limits["brake_kv"] == 4000.0  # positive: the damper's gain is -kv
    assert limits["wheel_radius"] == 0.45 and limits["max_steer"] == 1.2
    assert limits["mass"] == pytest.approx(14830.0)
    tractor = next(m for m in task.movers if type(m).__name__ == "Tractor")
    assert tractor.drive_geometry(physics) == pytest.approx((1.6, 0.4))


@pytest.mark.parametrize("undo", ["sensors", "midphase"])
def test_the_physics_shortcuts_change_nothing(monkeypatch, undo):
    """What the task and scene files skip for speed leaves every trajectory bit-identical: sensors on the fused
    substeps (computed only where read: the contact sensor at every collision check, all of them at the end of
    the control step) and the collision midphase. Each is undone in turn and an episode of the agent driving into
    a parked aircraft among two movers is compared step by step."""
    import deck_sim.tasks.physics_step as physics_step

    def run(undo: str | None) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
        env = deck_sim.load("deck1", seed=3, movers__tractors=2, movers__aircraft=0)
        env.reset()  # (composer compiles the model on the first reset: change its options after it)
        opt = env.physics.model.opt
        midphase = int(mujoco.mjtDisableBit.mjDSBL_MIDPHASE)
        assert opt.disableflags & midphase  # what the scene files set
        if undo == "midphase":
            opt.disableflags &= ~midphase
        task = env.task
        parked = task.planner_view().statics.centers[:-1]
        target = parked[np.argmin(np.linalg.norm(parked - task.last_info["position"], axis=1))]
        qpos, sensors, hits = [], [], []
        for _ in range(200):  # drive at the nearest parked aircraft until the collision ends the episode
            direction = target - task.last_info["position"]
            ts = env.step(direction / np.linalg.norm(direction))
            qpos.append(env.physics.data.qpos.copy())
            sensors.append(env.physics.data.sensordata.copy())
            hits.append(task.last_info["collision"])
            if ts.last():
                break
        assert bool(env.physics.model.opt.disableflags & midphase) == (undo != "midphase")  # still as set
        return np.array(qpos), np.array(sensors), hits

    fast = run(None)
    if undo == "sensors":
        monkeypatch.setattr(physics_step, "_NO_SENSORS", 0)  # every substep computes its sensors
    plain = run(undo)
    assert plain[2][-1] is not None and plain[2][-1].startswith("parked_aircraft")
    assert np.array_equal(fast[0], plain[0])
    assert np.array_equal(fast[1], plain[1])
    assert fast[2] == plain[2]


@pytest.mark.parametrize("scene", ["deck1", "deck2"])
def test_every_vehicle_starts_an_episode_at_rest_on_its_wheels(scene):
    """The agent and every wheeled mover are placed with their wheels on the deck, not dropped onto it: over the
    first control step no free body sinks or rises by more than a centimetre or moves vertically faster than
    5 cm/s."""
    env = deck_sim.load(scene, seed=3)
    for episode in range(2):
        env.reset()
        m, d = env.physics.model.ptr, env.physics.data.ptr
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        assert len(free) >= 2  # the agent and at least one wheeled mover
        z0 = np.array([d.qpos[m.jnt_qposadr[j] + 2] for j in free])
        env.step(np.zeros(2))
        z1 = np.array([d.qpos[m.jnt_qposadr[j] + 2] for j in free])
        vz = np.array([d.qvel[m.jnt_dofadr[j] + 2] for j in free])
        assert np.all(np.abs(z1 - z0) < 0.01), (episode, z1 - z0)
        assert np.all(np.abs(vz) < 0.05), (episode, vz)
