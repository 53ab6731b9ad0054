"""Scene specs: loading, overrides and errors that name the field and the value."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import deck_sim
from deck_sim.scenes import SceneSpecError, load_scene, parse_scene, scene_names

try:
    import tomllib
except ImportError:  # pragma: no cover
    import tomli as tomllib

from deck_sim.scenes import SCENE_DIR


def _deck1() -> dict:
    return tomllib.loads((SCENE_DIR / "deck1.toml").read_text())


def test_shipped_scenes_load():
    assert scene_names() == ["deck1", "deck1-multi", "deck2", "deck2-multi", "square"]
    for name in scene_names():
        spec = load_scene(name)
        assert spec.name == name
        assert spec.multi_agent == name.endswith("-multi")


def test_unknown_scene_name_is_named():
    with pytest.raises(SceneSpecError, match="unknown scene 'deck9'.*deck1, deck1-multi, deck2, deck2-multi, square"):
        deck_sim.load("deck9")


def test_missing_file_is_named(tmp_path):
    with pytest.raises(SceneSpecError, match="does not exist"):
        load_scene(tmp_path / "nope.toml")


def test_invalid_toml_is_named(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed\n")
    with pytest.raises(SceneSpecError, match="bad.toml: not valid TOML"):
        load_scene(bad)


def test_wrong_type_names_field_and_value(tmp_path):
    text = (SCENE_DIR / "deck1.toml").read_text().replace("reach = 3.0", 'reach = "far"')
    path = tmp_path / "deck1x.toml"
    path.write_text(text)
    with pytest.raises(SceneSpecError, match=r"\[agent\]\.reach: expected a number, got 'far'"):
        load_scene(path)


def test_unknown_field_is_named():
    data = _deck1()
    data["movers"]["wheels"] = 4
    with pytest.raises(SceneSpecError, match=r"unknown field\(s\) \['wheels'\]"):
        parse_scene(data, "deck1.toml")


def test_missing_section_and_field_are_named():
    data = _deck1()
    del data["reward"]
    with pytest.raises(SceneSpecError, match=r"missing section \[reward\]"):
        parse_scene(data)
    data = _deck1()
    del data["agent"]["reach"]
    with pytest.raises(SceneSpecError, match="missing required field 'reach'"):
        parse_scene(data)


def test_semantic_errors_are_named():
    data = _deck1()
    data["episode"]["physics_timestep"] = 0.3
    with pytest.raises(SceneSpecError, match="does not divide control_period"):
        parse_scene(data)
    data = _deck1()
    data["static"]["slotted"] = 14
    with pytest.raises(SceneSpecError, match="paper_counts"):
        parse_scene(data)
    data = _deck1()
    data["reward"]["attraction_min"] = 5.0
    with pytest.raises(SceneSpecError, match=r"l <= L"):
        parse_scene(data)
    for section, name, value in (
        ("episode", "near_steps", -1),
        ("episode", "route_steps", -2),
        ("movers", "agent_yield_braking", -1.0),
    ):
        data = _deck1()
        data[section][name] = value
        with pytest.raises(SceneSpecError, match=rf"\[{section}\]\.{name}: must be >= 0, got {value}"):
            parse_scene(data)


def test_a_lookahead_beyond_the_horizon_or_with_several_aircraft_is_refused_by_name():
    with pytest.raises(SceneSpecError, match=r"\[reward\]\.lookahead_steps: expected 0 <= lookahead_steps <= "
                                             r"episode.horizon 10, got 11"):
        load_scene("deck1", reward__lookahead_steps=11)
    with pytest.raises(SceneSpecError, match="expected one of"):
        load_scene("deck1", reward__lookahead_steps=4, reward__lookahead_predictor="none")
    with pytest.raises(SceneSpecError, match="several agents need lookahead_steps = 0"):
        load_scene("deck1-multi", reward__lookahead_steps=4)
    with pytest.raises(SceneSpecError, match=r"\[episode\]\.history: reward.lookahead_predictor 'mpc' reads the last"):
        load_scene("deck1", reward__lookahead_steps=4, episode__history=2)
    with pytest.raises(SceneSpecError, match=r"\[reward\]\.lookahead_predictor: reward.lookahead_predictor 'mpc' is "
                                             r"compiled for at most \d+ movers"):
        load_scene("deck1", reward__lookahead_steps=4, movers__tractors=40)
    assert load_scene("deck1", reward__lookahead_steps=4, episode__history=2,
                      reward__lookahead_predictor="constant_velocity").reward.lookahead_steps == 4


def test_overrides_apply_and_are_validated():
    spec = load_scene("deck1", episode__predictor="oracle", episode__horizon=4)
    assert spec.episode.predictor == "oracle" and spec.episode.horizon == 4
    with pytest.raises(SceneSpecError, match="expected one of"):
        load_scene("deck1", episode__predictor="crystal_ball")
    with pytest.raises(SceneSpecError, match="override 'predictor'"):
        load_scene("deck1", predictor="oracle")
    # a movers' field reaches the movers' behaviour of the task built from it
    env = deck_sim.load("deck1", seed=0, movers__agent_yield_braking=1.5)
    assert env.task._behaviour.params.agent_yield_braking == 1.5


def test_unknown_site_is_named(tmp_path):
    text = (SCENE_DIR / "deck1.toml").read_text().replace('"start_1",', '"start_99",')
    path = tmp_path / "deck1y.toml"
    path.write_text(text)
    with pytest.raises(SceneSpecError, match=r"\[agent\]\.start_sites\[0\]: the deck arena has no site 'start_99'"):
        deck_sim.load(path)  # at load, before any model is built


NUMBER_FIELDS = [
    ("agent", "reach"),
    ("agent", "goal_radius"),
    ("movers", "accel"),
    ("reward", "influence_radius"),
    ("episode", "time_limit"),
]


@settings(max_examples=60, deadline=None)
@given(
    field=st.sampled_from(NUMBER_FIELDS),
    value=st.one_of(
        st.text(max_size=5),
        st.booleans(),
        st.lists(st.integers(), max_size=2),
        st.just(math.nan),
        st.just(math.inf),
    ),
)
def test_any_malformed_number_is_rejected_naming_the_field(field, value):
    data = _deck1()
    section, name = field
    data[section][name] = value
    with pytest.raises(SceneSpecError) as err:
        parse_scene(data, "deck1.toml")
    assert f"[{section}].{name}" in str(err.value)


@settings(max_examples=40, deadline=None)
@given(value=st.floats(min_value=-1e6, max_value=0.0, allow_nan=False))
def test_non_positive_reach_is_rejected(value):
    data = _deck1()
    data["agent"]["reach"] = value
    with pytest.raises(SceneSpecError, match=r"\[agent\]\.reach"):
        parse_scene(data)


def test_dump_scene_reads_back_equal_with_overrides():
    from deck_sim.scenes import dump_scene

    specs = [load_scene(name) for name in scene_names()]
    specs += [load_scene(name, episode__predictor="mpc", reward__goal=123.25) for name in scene_names()]
    specs.append(load_scene("deck1", movers__tractors=2))
    specs.append(load_scene("deck1-multi", agents__count=7))  # counts changed: no paper_counts any more
    for spec in specs:
        assert parse_scene(tomllib.loads(dump_scene(spec)), "dumped") == spec


def test_a_scene_file_extends_another_and_replaces_only_what_it_sets(tmp_path):
    from deck_sim.scenes import load_scene

    deck1 = load_scene("deck1")
    child = tmp_path / "busy.toml"
    child.write_text('extends = "deck1"\nname = "busy"\n\n[movers]\ntractors = 6\n')
    spec = load_scene(child)
    assert spec.name == "busy" and spec.movers.tractors == 6
    assert spec.movers.aircraft == deck1.movers.aircraft and spec.reward == deck1.reward and spec.agent == deck1.agent
    grandchild = tmp_path / "busier.toml"
    grandchild.write_text('extends = "busy.toml"\nname = "busier"\n\n[movers]\naircraft = 2\n')
    spec = load_scene(grandchild)  # a path relative to the extending file
    assert (spec.movers.tractors, spec.movers.aircraft) == (6, 2)
    # deck 2 is deck 1 with more movers: every section but the movers' is deck 1's
    deck2 = load_scene("deck2")
    assert deck2.agent == deck1.agent and deck2.static == deck1.static and deck2.episode == deck1.episode


def test_a_bad_extends_is_refused_with_the_file_named(tmp_path):
    from deck_sim.scenes import SceneSpecError, load_scene

    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text('extends = "b.toml"\nname = "a"\n')
    b.write_text('extends = "a.toml"\nname = "b"\n')
    with pytest.raises(SceneSpecError, match=r"extend each other in a cycle \(a.toml -> b.toml -> a.toml\)"):
        load_scene(a)
    a.write_text('extends = "nowhere"\n')
    with pytest.raises(SceneSpecError, match="unknown scene 'nowhere'"):
        load_scene(a)
    a.write_text("extends = 3\n")
    with pytest.raises(SceneSpecError, match="a.toml: extends: expected a scene name"):
        load_scene(a)
