"""Scene values that have the right type but are wrong are refused when the scene loads, naming the field; the CLI
reports them in one line with exit code 2; the bounds are the ones the models and the arenas hold."""

import dataclasses
import logging
import subprocess
import sys
import typing
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import deck_sim
from deck_sim.cli import main
from deck_sim.control.tracking import AircraftLimits, track_displacement
from deck_sim.scenes import (
    MAX_PHYSICS_TIMESTEP,
    SECTIONS,
    AgentSpec,
    AgentsSpec,
    EpisodeSpec,
    MoverSpec,
    RewardSpec,
    SceneSpecError,
    StaticSpec,
    load_scene,
    scene_names,
)
from deck_sim.scenes.arena_facts import ASSETS, arena_facts, vehicle_top_speeds
from deck_sim.tasks.layout import LayoutError

REFUSED = [  # (scene, overrides, what the message says)
    ("deck1", {"static__scattered": 5}, r"\[static\]\.scattered: 5 standing groups cannot share a scene with aircraft"),
    ("square", {"movers__aircraft": 1}, r"\[static\]\.scattered: .* aircraft \(movers\.aircraft = 1\)"),
    ("deck1", {"static__slotted": 27}, r"\[static\]\.slotted: must be 0 to the 26 'park_\*' slots"),
    ("deck1", {"static__slot_prefix": ""}, r"\[static\]\.slot_prefix: must not be empty"),
    ("deck1", {"static__slot_prefix": "spot_"}, r"\[static\]\.slot_prefix: 'spot_' makes site\(s\) .* slots"),
    ("deck1", {"agent__start_sites": ["nowhere"]}, r"\[agent\]\.start_sites\[0\]: the deck arena has no site "
     r"'nowhere'; its sites are .*start_1"),
    ("square", {"movers__spots": ["spot_shop_1", "atm_9"]}, r"\[movers\]\.spots\[1\]: the square arena has no site"),
    ("deck1", {"movers__spots": ["spot_fuel_1", "spot_fuel_1"]}, r"\[movers\]\.spots: name\(s\) \['spot_fuel_1'\]"),
    ("deck1", {"episode__physics_timestep": 1e-300}, r"\[episode\]\.physics_timestep: must be >= 0\.001"),
    ("deck1", {"episode__physics_timestep": 0.5}, r"\[episode\]\.physics_timestep: must be <= 0\.03125 s, the "
     r"largest timestep the models are stable at"),
    ("deck1", {"episode__history": 10**30}, r"\[episode\]\.history: must be <= 1000"),
    ("deck1", {"episode__time_limit": 10**30}, r"\[episode\]\.time_limit: must be <= 3600"),
    ("deck1", {"episode__time_limit": 10**400}, r"\[episode\]\.time_limit: expected a finite number, got an "
     r"integer of 401 digits"),
    ("deck1", {"episode__control_period": 200.0}, r"\[episode\]\.control_period: must be <= 180"),
    ("deck1", {"episode__horizon": 100_000}, r"\[episode\]\.horizon: must be <= 100"),
    ("deck1", {"episode__route_steps": 100_000}, r"\[episode\]\.route_steps: .* exceeds the arena's perimeter"),
    ("deck1", {"episode__near_steps": 10**400}, r"\[episode\]\.near_steps: .* exceeds the arena's diagonal"),
    ("deck1", {"episode__predictor": "mpc", "movers__tractors": 20}, r"\[episode\]\.predictor: 'mpc' is compiled "
     r"for at most 16 movers, the scene has 21"),
    ("deck1", {"episode__predictor": "mpc", "episode__history": 5}, r"\[episode\]\.history: .* reads the last 10"),
    ("deck1", {"movers__tractors": -1}, r"\[movers\]\.tractors: must be >= 0, got -1"),
    ("deck1", {"movers__aircraft": -1, "movers__tractors": 5}, r"\[movers\]\.aircraft: must be >= 0, got -1"),
    ("deck1", {"movers__tractors": -5}, r"\[movers\]\.tractors: must be >= 0, got -5"),
    ("deck1", {"movers__tractors": 1_000_000_000_000}, r"\[movers\]\.tractors: 1000000000000 tractors .* more than "
     r"the 64"),
    ("deck1", {"movers__aircraft": 17}, r"\[movers\]\.aircraft: must be <= 16"),
    ("deck2", {"movers__tractors": 0, "movers__aircraft": 1}, r"\[movers\]\.spawn_near_agent: .* exceed the 1 "
     r"movers"),
    ("deck1", {"movers__spawn_random": -2}, r"\[movers\]\.spawn_random: must be >= 0"),
    ("deck1", {"movers__speed_range": [2.0, 10.0]}, r"\[movers\]\.speed_range: the top cruise speed 10 m/s exceeds "
     r"the tractor's top speed 6 m/s"),
    ("deck1", {"movers__pedestrians": 3}, r"\[movers\]\.speed_range: .* pedestrian's top speed 3 m/s "
     r"\(movers\.pedestrians = 3\)"),
    ("deck1", {"movers__dwell_range": [3.0, 1e9]}, r"\[movers\]\.dwell_range: expected 0 <= min <= max <= 3600"),
    ("deck1", {"movers__decel": 0.0}, r"\[movers\]\.decel: must be >= 0\.05"),
    ("deck1", {"movers__accel": 100.0}, r"\[movers\]\.accel: must be <= 9\.81"),
    ("deck1", {"movers__turn_rate": 100.0}, r"\[movers\]\.turn_rate: must be <= 6\.28"),
    ("deck1", {"movers__yield_distance": -1.0}, r"\[movers\]\.yield_distance: must be >= 0, got -1\.0"),
    ("deck1", {"movers__clearance": -1.0}, r"\[movers\]\.clearance: must be >= 0"),
    ("deck1", {"movers__near_radius": -1.0}, r"\[movers\]\.near_radius: must be >= 0"),
    ("deck1", {"movers__agent_yield_distance": -2.0}, r"\[movers\]\.agent_yield_distance: must be >= 0"),
    ("deck1", {"movers__agent_yield_braking": 50.0}, r"\[movers\]\.agent_yield_braking: must be <= 9\.81"),
    ("square", {"static__scatter_clearance": -1.0}, r"\[static\]\.scatter_clearance: must be >= 0"),
    ("deck1", {"agent__start_jitter": -1.0}, r"\[agent\]\.start_jitter: must be >= 0"),
    ("deck1", {"agent__target_jitter": -1.0}, r"\[agent\]\.target_jitter: must be >= 0"),
    ("deck1", {"agent__start_jitter": 100.0}, r"\[agent\]\.start_jitter: 100\.0 m puts site\(s\) .* off the deck"),
    ("deck1", {"agent__yaw_jitter": 4.0}, r"\[agent\]\.yaw_jitter: must be <= 3\.14"),
    ("deck1", {"agent__reach": 4.0}, r"\[agent\]\.reach: must be <= 3 m \(agent\.vehicle 'aircraft': its top "
     r"speed 6 m/s"),
    ("deck1", {"episode__control_period": 0.25}, r"\[agent\]\.reach: .* over episode\.control_period 0\.25 s"),
    ("deck1", {"agent__radius": 50.0}, r"\[agent\]\.radius: must be <= 38\.4"),
    ("deck1", {"agent__min_target_distance": 250.0, "agent__max_target_distance": 400.0},
     r"\[agent\]\.min_target_distance: no site of agent\.target_sites lies 250-400 m from the start site"),
    ("deck1", {"reward__collision": 5.0}, r"\[reward\]\.collision: must be <= 0"),
    ("deck1", {"reward__w_goal": -1.0}, r"\[reward\]\.w_goal: must be >= 0"),
    ("deck1", {"reward__goal": 1e308, "reward__w_goal": 10.0}, r"\[reward\]\.w_goal: .* is not a finite number"),
    ("deck1", {"reward__progress_deadband": 5.0}, r"\[reward\]\.progress_deadband: .* < agent\.reach 3\.0 m"),
    ("deck1", {"reward__influence_radius": 1e6}, r"\[reward\]\.influence_radius: must be <= 341\.59"),
]


@pytest.mark.parametrize("scene, overrides, message", REFUSED, ids=[str(c[1]) for c in REFUSED])
def test_a_wrong_value_is_refused_at_load_naming_the_field(scene, overrides, message):
    with pytest.raises(SceneSpecError, match=message):
        load_scene(scene, **overrides)
    with pytest.raises(SceneSpecError, match=message):
        deck_sim.load(scene, seed=0, **overrides)  # before any model is built


CLI_REFUSED = [  # (--scene-set values, the field the message names)
    (["static.scattered=5"], "[static].scattered"),
    (["static.slotted=27"], "[static].slotted"),
    (['agent.start_sites=["nowhere"]'], "[agent].start_sites[0]"),
    (["episode.physics_timestep=1e-300"], "[episode].physics_timestep"),
    (["episode.physics_timestep=0.5"], "[episode].physics_timestep"),
    ([f"episode.history={10**30}"], "[episode].history"),
    ([f"episode.time_limit={10**30}"], "[episode].time_limit"),
    ([f"episode.time_limit={10**400}"], "[episode].time_limit"),
    (["movers.tractors=-1"], "[movers].tractors"),
    (["movers.tractors=1000000000000"], "[movers].tractors"),
    (["static.slot_prefix="], "[static].slot_prefix"),
]


@pytest.mark.parametrize("sets, field", CLI_REFUSED, ids=[c[0][0][:40] for c in CLI_REFUSED])
def test_the_cli_reports_a_wrong_value_in_one_line_with_exit_code_2(tmp_path, capsys, sets, field):
    args = ["run", "--episodes", "1", "--no-record", "--quiet", "--out", str(tmp_path)]
    assert main([*args, *(x for s in sets for x in ("--scene-set", s))]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("deck-sim run: error: deck1.toml ") and "\n" not in err
    assert field in err
    assert not any(tmp_path.iterdir())  # refused before anything was run or written


def test_a_field_given_twice_on_the_cli_is_refused(tmp_path, capsys):
    args = ["run", "--episodes", "1", "--no-record", "--quiet", "--out", str(tmp_path)]
    sets = ["--scene-set", "movers.tractors=2", "--scene-set", "movers.tractors=3"]
    assert main([*args, *sets]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "deck-sim run: error: --scene-set movers.tractors is given twice (2, then 3); give each field once"


def test_a_layout_that_cannot_be_drawn_is_a_clear_error(tmp_path, capsys):
    assert issubclass(LayoutError, ValueError)
    args = ["run", "--scene", "square", "--episodes", "1", "--no-record", "--quiet", "--out", str(tmp_path)]
    assert main([*args, "--scene-set", "static.scatter_clearance=30"]) == 2  # loads, but no group fits
    err = capsys.readouterr().err.strip()
    assert err == "deck-sim run: error: square: could not place standing group 1 of 20 with 30.0 m clearance after " \
        "2000 tries"


def test_a_scene_file_that_is_binary_or_a_directory_is_refused(tmp_path):
    binary = tmp_path / "binary.toml"
    binary.write_bytes(bytes(range(256)))
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    with pytest.raises(SceneSpecError, match="binary.toml: not a TOML file"):
        deck_sim.load(binary)
    with pytest.raises(SceneSpecError, match="folder.toml is a directory"):
        deck_sim.load(folder)
    section = tmp_path / "section.toml"
    section.write_text('extends = "deck1"\nagent = 3\n')
    with pytest.raises(SceneSpecError, match=r"section.toml \[agent\]: expected a table, got 3"):
        load_scene(section, agent__reach=1.0)


def test_the_arena_facts_are_those_of_the_compiled_arenas():
    from deck_sim.entities.arenas import make_arena

    for kind in ("deck", "square"):
        arena, facts = make_arena(kind), arena_facts(kind)
        assert {n: (s.x, s.y) for n, s in arena.sites.items()} == facts.sites
        assert np.array_equal(arena.bounds, np.array([facts.lo, facts.hi]))
    tractor = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_tractor.xml"))
    wheel = mujoco.mj_name2id(tractor, mujoco.mjtObj.mjOBJ_GEOM, "left_wheel")
    pedestrian = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_pedestrian.xml"))
    assert vehicle_top_speeds() == {
        "tractor": float(tractor.actuator_ctrlrange.max() * tractor.geom_size[wheel, 0]),
        "aircraft": AircraftLimits(mass=1.0).max_speed,
        "pedestrian": float(pedestrian.actuator_ctrlrange.max()),
    }


def test_a_vehicle_faster_than_its_scene_allows_ends_the_episode_as_diverged(envs):
    env = envs["deck1"]
    stepper = env.task._stepper
    assert stepper.runaway_speed == pytest.approx(10 * 6.0)  # ten times the aircraft's and the tractor's top speed
    assert envs["square"].task._stepper.runaway_speed == pytest.approx(10 * 3.0)  # ... the pedestrians'
    env.reset()
    env.step(np.array([0.5, 0.0]))
    dof = stepper._vel_dofs[0]
    env.physics.data.qvel[dof] = [80.0, 0.0]  # no MuJoCo warning for this: only the speed tells
    ts = env.step(np.array([0.5, 0.0]))
    assert ts.last() and env.task.last_info["diverged"]


def test_no_mover_is_reported_lost_after_mujoco_resets_a_diverged_state(envs, caplog):
    env = envs["deck1"]
    env.reset()
    env.step(np.array([0.5, 0.0]))
    env.physics.data.qvel[:] = 1e12  # MuJoCo warns and resets every body to the origin, off the deck's edge
    with caplog.at_level(logging.WARNING, logger="deck_sim"):
        env.step(np.array([0.5, 0.0]))
    assert env.task.last_info["diverged"] and env.task.last_info["movers_rescued"] == 0
    assert not [r for r in caplog.records if "left the surface" in r.getMessage()]
    assert [r for r in caplog.records if "physics diverged" in r.getMessage()]


def _tractor_speed_ripple(dt: float) -> float:
    """Largest relative deviation from its wheel speed (3.2 m/s) of the tractor's speed over its fifth second."""
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_tractor.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    model.opt.timestep = dt
    data.ctrl[:] = [8.0, 8.0]
    speeds = []
    for _ in range(round(5.0 / dt)):
        mujoco.mj_step(model, data)
        speeds.append(data.qvel[0])
    return float(np.abs(np.array(speeds[-round(1.0 / dt) :]) / 3.2 - 1.0).max())


def _aircraft(dt: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "scene_aircraft.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    model.opt.timestep = dt
    return model, data


def _yaw(quat: np.ndarray) -> float:
    w, x, y, z = quat
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _aircraft_speed_after_braking(dt: float) -> float:
    """m/s: the aircraft's speed after 6 s of full thrust, then 6 s of full brakes."""
    model, data = _aircraft(dt)
    data.ctrl[:] = [0.0, 0.5, 0.0, 0.0]
    mujoco.mj_step(model, data, nstep=round(6.0 / dt))
    data.ctrl[:] = [0.0, 0.0, 1.0, 1.0]
    mujoco.mj_step(model, data, nstep=round(6.0 / dt))
    return float(np.hypot(*data.qvel[:2]))


def _tracker_heading_error(dt: float) -> float:
    """Radians: the worst heading error after the tracker has 12 s to turn the aircraft round from rest (to 90 and
    to 175 degrees), at 0.5 s decisions."""
    model, data = _aircraft(dt)
    limits = AircraftLimits(mass=float(model.body_subtreemass[1]))
    worst = 0.0
    for goal in (np.pi / 2, np.radians(175)):
        mujoco.mj_resetDataKeyframe(model, data, 0)
        for _ in range(24):
            yaw = _yaw(data.qpos[3:7])
            speed = data.qvel[0] * np.cos(yaw) + data.qvel[1] * np.sin(yaw)
            cmd = track_displacement(3 * np.cos(goal), 3 * np.sin(goal), yaw, speed, 0.5, limits)
            data.ctrl[:] = [cmd.steer, cmd.thrust, cmd.brake, cmd.brake]
            mujoco.mj_step(model, data, nstep=round(0.5 / dt))
        worst = max(worst, abs((goal - _yaw(data.qpos[3:7]) + np.pi) % (2 * np.pi) - np.pi))
    return worst


def test_the_models_hold_up_to_the_largest_timestep_and_not_beyond():
    # at the bound: the tractor holds its wheel speed, the aircraft brakes to a stop, the tracker turns it round
    assert MAX_PHYSICS_TIMESTEP == 1 / 32
    assert _tractor_speed_ripple(1 / 32) < 0.03
    assert _aircraft_speed_after_braking(1 / 32) < 0.05
    assert _tracker_heading_error(1 / 32) < np.radians(10)
    # the next timesteps that divide the 0.5 s decision: each fails one check
    assert _tractor_speed_ripple(1 / 24) > 0.03
    assert _aircraft_speed_after_braking(1 / 20) > 0.05
    assert _tracker_heading_error(1 / 8) > np.radians(10)


def test_a_runaway_at_a_coarse_timestep_is_flagged_as_divergence():
    from deck_sim.environment import make_environment

    spec = load_scene("deck1", episode__predictor="none", episode__collision_checks=1)
    coarse = dataclasses.replace(spec, episode=dataclasses.replace(spec.episode, physics_timestep=0.3))  # unchecked
    env = make_environment(coarse, seed=1000)
    ts = env.reset()
    while not ts.last():
        ts = env.step(np.array([1.0, 0.0]))  # full speed ahead
    assert env.task.last_info["diverged"]  # an aircraft ran away; MuJoCo did not warn


@pytest.mark.slow
def test_the_largest_scenes_compile_and_two_dozen_taxiing_aircraft_do_not():
    from deck_sim.tasks.navigate import Navigate

    def compiles(spec) -> bool:
        root = Navigate(spec).root_entity.mjcf_model
        model = mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
        try:
            mujoco.mj_forward(model, mujoco.MjData(model))  # every body at the origin, as composer compiles it
        except mujoco.FatalError:
            return False
        return True

    quiet = {"episode__predictor": "none", "movers__spawn_near_agent": 0, "movers__spawn_random": 0}
    assert compiles(load_scene("deck1", movers__aircraft=16, movers__tractors=48, static__slotted=26, **quiet))
    assert compiles(load_scene("square", movers__pedestrians=64, static__scattered=64, static__slotted=12, **quiet))
    spec = load_scene("deck1", movers__tractors=0, **quiet)
    assert not compiles(dataclasses.replace(spec, movers=dataclasses.replace(spec.movers, aircraft=24)))


def test_mujoco_cannot_collide_a_capsule_lying_on_a_cylinder():
    # why standing groups (cylinders) and aircraft (capsule fuselages) cannot share a scene: MuJoCo reserves two
    # contacts for a capsule-cylinder pair, its collider returns four for a capsule across the cylinder's cap. Run
    # apart: past the reserved room the process may abort. When this fails, MuJoCo handles it: lift the bound.
    code = """
import mujoco
xml = '''<mujoco><worldbody>
<body><geom type="cylinder" pos="0 0 0.85" size="1.2 0.85"/></body>
<body pos="0 0 1.8"><freejoint/><geom type="capsule" fromto="-8.3 0 0 8.2 0 0" size="0.9"/></body>
</worldbody></mujoco>'''
model = mujoco.MjModel.from_xml_string(xml)
assert mujoco.mj_maxContact(model, 0, 1, -1) == 2
mujoco.mj_forward(model, mujoco.MjData(model))
print("collided")
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and "collided" not in run.stdout
    assert "pairMaxContact" in run.stderr or run.returncode < 0


# -- property tests: any bad value of any field is refused naming the field, or loads -----------------------------

_SPECS = {
    "agent": AgentSpec,
    "static": StaticSpec,
    "movers": MoverSpec,
    "reward": RewardSpec,
    "episode": EpisodeSpec,
    "agents": AgentsSpec,
}
FIELDS = [(section, f.name) for section in SECTIONS for f in dataclasses.fields(_SPECS[section])]

_NUMBERS = st.one_of(
    st.integers(min_value=-(10**30), max_value=10**30),
    st.integers(min_value=10**300, max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 0.0, -0.0, 1e-300, 5e-324, 1e308, -1e308, 0.5, 1.0, 2, 3]),
)
_BAD = st.one_of(
    _NUMBERS,
    st.booleans(),
    st.none(),
    st.text(max_size=8),
    st.sampled_from(["", "start_1", "spot_fuel_1", "park_", "kiosk_", "mpc", "agent", "nowhere"]),
    st.lists(st.one_of(_NUMBERS, st.text(max_size=6), st.sampled_from(["start_1", "spot_shop_1"])), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)


def _in_message(section: str, name: str, message: str) -> bool:
    return name in message and (f"[{section}]" in message or f"{section}." in message or f"{section}__" in message)


@settings(max_examples=400, deadline=None)
@given(scene=st.sampled_from(scene_names()), field=st.sampled_from(FIELDS), value=_BAD)
def test_any_bad_value_of_any_field_is_refused_naming_it_or_loads(scene, field, value):
    section, name = field
    try:
        load_scene(scene, **{f"{section}__{name}": value})
    except SceneSpecError as err:
        assert _in_message(section, name, str(err)), str(err)


@settings(max_examples=60, deadline=None)
@given(
    scene=st.sampled_from(scene_names()),
    section=st.one_of(st.sampled_from(SECTIONS), st.text(min_size=1, max_size=6)),
    name=st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8),
    value=_BAD,
)
def test_an_unknown_field_or_section_is_refused_naming_it(scene, section, name, value):
    known = section in _SPECS and name in {f.name for f in dataclasses.fields(_SPECS[section])}
    if known:
        return  # a real field: the test above
    with pytest.raises(SceneSpecError) as err:
        load_scene(scene, **{f"{section}__{name}": value})
    assert name in str(err.value)


def test_every_numeric_field_has_its_bounds_in_its_docstring():
    text = Path(deck_sim.scenes.__file__).read_text()
    for section, name in FIELDS:
        hint = typing.get_type_hints(_SPECS[section])[name]
        if hint in (int, float) or typing.get_origin(hint) is tuple and typing.get_args(hint)[0] in (int, float):
            doc = " ".join(text.split(f"    {name}: ", 1)[1].split('"""', 2)[1].split()).lower()
            assert any(w in doc for w in (">", "<", " to ", "in [", "in (", "at most", "at least")), (section, name)
