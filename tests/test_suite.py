"""dm_control suite_test style checks over every scene: determinism, specs, counts, finite rewards."""

import numpy as np
import pytest
from conftest import SCENES, run_steps

import deck_sim
from deck_sim.scenes import load_scene

PAPER_COUNTS = {"deck1": (15, 5), "deck2": (15, 9), "square": (28, 13)}


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_same_seed_gives_bit_identical_episodes(scene):
    a = deck_sim.load(scene, seed=7)
    b = deck_sim.load(scene, seed=7)
    obs_a, rew_a = run_steps(a, 40, seed=3)
    obs_b, rew_b = run_steps(b, 40, seed=3)
    assert rew_a == rew_b
    for oa, ob in zip(obs_a, obs_b, strict=True):
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key])


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_the_plain_observation_path_gives_composers_observations(scene):
    from deck_sim.environment import DeckEnvironment, make_environment

    fast = make_environment(load_scene(scene), seed=5)
    slow = make_environment(load_scene(scene), seed=5, plain_observations=False)
    assert isinstance(fast, DeckEnvironment) and not isinstance(slow, DeckEnvironment)
    assert fast.observation_spec() == slow.observation_spec()
    obs_f, rew_f = run_steps(fast, 60, seed=4)
    obs_s, rew_s = run_steps(slow, 60, seed=4)
    assert rew_f == rew_s and len(obs_f) == len(obs_s)
    for of, os_ in zip(obs_f, obs_s, strict=True):
        assert list(of) == list(os_)
        for key in of:
            assert of[key].dtype == os_[key].dtype and of[key].shape == os_[key].shape
            np.testing.assert_array_equal(of[key], os_[key])
    # every observation is a copy: stepping on does not change one already returned
    held = fast.reset().observation
    first = {k: v.copy() for k, v in held.items()}
    fast.step(np.array([0.5, 0.0]))
    for key in first:
        np.testing.assert_array_equal(held[key], first[key])


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_different_seeds_give_different_layouts(scene):
    a = deck_sim.load(scene, seed=1).reset().observation
    b = deck_sim.load(scene, seed=2).reset().observation
    assert not np.array_equal(a["static_obstacles"], b["static_obstacles"])


@pytest.mark.parametrize("scene", SCENES)
def test_observation_and_action_specs_conform(envs, scene):
    env = envs[scene]
    obs_spec, act_spec = env.observation_spec(), env.action_spec()
    assert act_spec.shape == (2,)
    np.testing.assert_array_equal(act_spec.minimum, -1.0)
    np.testing.assert_array_equal(act_spec.maximum, 1.0)
    obs, rewards = run_steps(env, 15)
    for o in obs:
        assert set(o) == set(obs_spec)
        for key, spec in obs_spec.items():
            assert o[key].shape == spec.shape, key
            assert np.all(np.isfinite(o[key])), key
    assert all(np.isfinite(r) for r in rewards)


@pytest.mark.parametrize("scene", SCENES)
def test_obstacle_counts_match_the_paper(envs, scene):
    spec = load_scene(scene)
    task = envs[scene].task
    assert (spec.static.count, spec.movers.count) == PAPER_COUNTS[scene]
    assert (len(task.statics), len(task.movers)) == PAPER_COUNTS[scene]
    shapes = task.observation_shapes
    assert shapes["dynamic_obstacles"] == (PAPER_COUNTS[scene][1], 2)
    # the deck's island is the one static obstacle of the arena itself, listed last
    extra = 1 if spec.arena == "deck" else 0
    assert shapes["static_obstacles"] == (PAPER_COUNTS[scene][0] + extra, 2)


@pytest.mark.parametrize("scene", SCENES)
def test_layout_is_non_overlapping(envs, scene):
    env = envs[scene]
    task = env.task
    for _ in range(3):
        env.reset()
        view = task.planner_view()
        assert view.statics.distance(view.agent_xy).min() > view.agent_radius
        # statics do not overlap each other (centre-to-footprint clearance of every pair)
        d = view.statics.distance(view.statics.centers)
        np.fill_diagonal(d, np.inf)
        assert d.min() > 0
        movers = view.movers.centers
        assert np.all(np.linalg.norm(movers - view.agent_xy, axis=1) > view.agent_radius)
        assert np.linalg.norm(view.target_xy - view.agent_xy) >= task.spec.agent.min_target_distance


@pytest.mark.parametrize("scene", SCENES)
def test_step_info_reports_the_step(envs, scene):
    env = envs[scene]
    run_steps(env, 3)
    info = env.task.last_info
    for key in (
        "position",
        "heading",
        "reward_terms",
        "collision",
        "distance_to_goal",
        "reached_goal",
        "left_surface",
        "diverged",
        "predictor_fallbacks",
        "min_clearance",
    ):
        assert key in info
    assert set(info["reward_terms"]) == {"r1", "r2", "r3", "r4", "total"}


@pytest.mark.slow
def test_obstacle_shape_observation_gives_nearest_points_and_headings():
    import deck_sim

    plain = deck_sim.load("deck1", seed=4)
    assert "static_nearest" not in plain.observation_spec()  # off by default: the paper's observation
    env = deck_sim.load("deck1", seed=4, episode__obstacle_shape=True)
    spec = env.observation_spec()
    m, n = spec["static_obstacles"].shape[0], spec["dynamic_obstacles"].shape[0]
    assert spec["static_nearest"].shape == (m, 2) and spec["dynamic_nearest"].shape == (n, 2)
    ts = env.reset()
    for _ in range(3):
        ts = env.step(np.array([0.5, 0.2]))
    obs = ts.observation
    view = env.task.planner_view()
    # each nearest point lies on its footprint's boundary, no farther than its centre, in the centres' order
    near = view.agent_xy + obs["static_nearest"]
    centre = view.agent_xy + obs["static_obstacles"]
    idx = [int(np.argmin(np.linalg.norm(view.statics.centers - c, axis=1))) for c in centre]
    dist = view.statics.distance(view.agent_xy)[0][idx]
    np.testing.assert_allclose(np.linalg.norm(obs["static_nearest"], axis=1), np.maximum(dist, 0), atol=1e-6)
    assert np.all(
        np.linalg.norm(obs["static_nearest"], axis=1) <= np.linalg.norm(obs["static_obstacles"], axis=1) + 1e-9
    )
    assert np.all(view.statics.distance(near)[np.arange(m), idx] < 1e-6)
    np.testing.assert_allclose(np.linalg.norm(obs["dynamic_heading"], axis=1), 1.0)
    assert np.all(
        np.linalg.norm(obs["dynamic_nearest"], axis=1) <= np.linalg.norm(obs["dynamic_obstacles"], axis=1) + 1e-9
    )


def test_mover_size_observation_follows_the_movers_order():
    import deck_sim

    assert "dynamic_size" not in deck_sim.load("deck1", seed=4).observation_spec()  # off by default
    env = deck_sim.load("deck1", seed=4, episode__mover_size=True)
    ts = env.reset()
    for _ in range(3):
        ts = env.step(np.array([0.5, 0.2]))
    obs, view = ts.observation, env.task.planner_view()
    assert obs["dynamic_size"].shape == obs["dynamic_obstacles"].shape
    # row k is the size of the mover whose centre is row k (nearest first)
    for rel, size in zip(obs["dynamic_obstacles"], obs["dynamic_size"], strict=True):
        k = int(np.argmin(np.linalg.norm(view.movers.centers - (view.agent_xy + rel), axis=1)))
        np.testing.assert_allclose(size, view.movers.half[k] + view.movers.radius[k])
    # one taxiing aircraft (17-18 m long) among tractors (about 4 m)
    lengths = sorted((2 * obs["dynamic_size"][:, 0]).tolist())
    assert lengths[-1] > 17.0 and lengths[0] < 5.0


@pytest.mark.slow
def test_near_obstacles_observation_gives_each_footprints_nearest_point_clipped_to_the_near_field():
    import deck_sim
    from deck_sim.geometry import clip_length
    from deck_sim.policies import ScriptedPolicy
    from deck_sim.scenes import SceneSpecError

    assert "static_near" not in deck_sim.load("square", seed=4, episode__near_steps=4).observation_spec()
    with pytest.raises(SceneSpecError, match=r"near_obstacles.*near_steps > 0"):
        deck_sim.load("square", seed=4, episode__near_obstacles=True)
    env = deck_sim.load(
        "square", seed=4, episode__near_steps=4, episode__near_obstacles=True, episode__obstacle_shape=True
    )
    spec = env.observation_spec()
    m, n = spec["static_obstacles"].shape[0], spec["dynamic_obstacles"].shape[0]
    assert spec["static_near"].shape == (m, 2) and spec["dynamic_near"].shape == (n, 2)
    near = 4 * env.task.spec.agent.reach
    policy = ScriptedPolicy(env)
    ts, closest = env.reset(), np.inf
    while not ts.last():
        obs = ts.observation
        # the footprints' nearest points (checked against the planner's view by the shape test), clipped
        np.testing.assert_allclose(obs["static_near"], clip_length(obs["static_nearest"], near), atol=1e-12)
        np.testing.assert_allclose(obs["dynamic_near"], clip_length(obs["dynamic_nearest"], near), atol=1e-12)
        lengths = np.linalg.norm(obs["static_near"], axis=1)
        assert np.all(lengths <= near + 1e-9)
        closest = min(closest, float(lengths.min()))
        ts = env.step(policy.act(obs))
    assert closest < near  # the walk passed an obstacle inside the near field
    # the agent's axes turn the new vectors like every other relative vector: expected from the planner's view
    from deck_sim.geometry import world_to_agent

    # (on the deck: the square's walker keeps its yaw, the aircraft turns)
    ego = deck_sim.load("deck1", seed=4, episode__near_steps=4, episode__near_obstacles=True, episode__frame="agent")
    near = 4 * ego.task.spec.agent.reach
    ts = ego.reset()
    for _ in range(6):
        ts = ego.step(np.array([0.5, 0.5]))  # ahead and to the left: the aircraft turns off the deck's axes
    obs, view = ts.observation, ego.task.planner_view()
    yaw = np.arctan2(obs["heading"][1], obs["heading"][0])
    assert abs(np.sin(yaw)) > 0.1  # a heading off the axes: a missed turn would show
    for key, fp in (("static_near", view.statics), ("dynamic_near", view.movers)):
        order = np.argsort(np.linalg.norm(fp.centers - view.agent_xy, axis=1), kind="stable")
        world_rows = clip_length(fp.nearest_points(view.agent_xy)[order] - view.agent_xy, near)
        np.testing.assert_allclose(obs[key], world_to_agent(world_rows, yaw), atol=1e-9, err_msg=key)


def test_near_observation_clips_the_target_and_the_edges_to_a_few_steps_reach():
    import deck_sim
    from deck_sim.policies import ScriptedPolicy

    assert "target_near" not in deck_sim.load("square", seed=4).observation_spec()  # off by default
    env = deck_sim.load("square", seed=4, episode__near_steps=4)
    near = 4 * env.task.spec.agent.reach  # 3 m on the square
    policy = ScriptedPolicy(env)
    ts, clipped, inside, at_edge = env.reset(), 0, 0, 0
    while True:
        # expected values from the planner's full-knowledge view, not from the observation itself
        obs, view = ts.observation, env.task.planner_view()
        (xmin, ymin), (xmax, ymax) = view.bounds
        to_target = view.target_xy - view.agent_xy
        length = float(np.linalg.norm(to_target))
        if length > near:  # the same direction, clipped to the range
            np.testing.assert_allclose(obs["target_near"], to_target * near / length)
            clipped += 1
        else:
            np.testing.assert_allclose(obs["target_near"], to_target)
            inside += 1
        x, y = view.agent_xy
        np.testing.assert_allclose(obs["edge_near"], np.minimum([x - xmin, xmax - x, y - ymin, ymax - y], near))
        at_edge += bool(np.any(obs["edge_near"] < near))
        if ts.last():
            break
        ts = env.step(policy.act(obs))
    # the planner walks to the cash machine, 1.5 m from the square's edge: every case was seen
    assert env.task.last_info["reached_goal"]
    assert clipped > 0 and inside > 0 and at_edge > 0


@pytest.mark.slow
def test_route_observation_follows_the_planners_way_round_the_statics():
    from deck_sim.control.planners import ScriptedPlanner, _point_along
    from deck_sim.policies import ScriptedPolicy

    assert "route" not in deck_sim.load("deck1", seed=5).observation_spec()  # off by default
    # no movers: the scripted planner's path is then the shortest way round the statics alone
    env = deck_sim.load("deck1", seed=5, episode__route_steps=6, movers__tractors=0, movers__aircraft=0)
    assert env.observation_spec()["route"].shape == (6, 2)
    reach = env.task.spec.agent.reach
    policy, planner = ScriptedPolicy(env), ScriptedPlanner()
    ts, bent, short = env.reset(), 0, 0
    while not ts.last():
        obs, view = ts.observation, env.task.planner_view()
        path = planner.path(view)  # expected values from the planner, not from the task's own method
        expected = np.array([_point_along(path, reach * k) for k in range(1, 7)]) - view.agent_xy
        np.testing.assert_allclose(obs["route"], expected, atol=1e-9)
        bent += len(path) > 2
        short += bool(np.allclose(obs["route"][-1], view.target_xy - view.agent_xy))
        ts = env.step(policy.act(obs))
    assert env.task.last_info["reached_goal"]
    assert bent > 5 and short > 0  # the path bent round a parked aircraft, and ended at the target
    with pytest.raises(deck_sim.SceneSpecError, match="route_steps"):
        deck_sim.load("deck1", episode__route_steps=-1)


def test_predicted_frame_mover_gives_each_movers_predicted_displacement():
    import deck_sim

    kw = {"seed": 4, "episode__predictor": "constant_velocity"}
    agent_frame = deck_sim.load("deck1", **kw)
    mover_frame = deck_sim.load("deck1", episode__predicted_frame="mover", **kw)
    a, b = agent_frame.reset(), mover_frame.reset()
    for _ in range(4):
        a, b = agent_frame.step(np.array([0.5, 0.2])), mover_frame.step(np.array([0.5, 0.2]))
    np.testing.assert_array_equal(a.observation["dynamic_obstacles"], b.observation["dynamic_obstacles"])
    np.testing.assert_allclose(
        b.observation["predicted"],
        a.observation["predicted"] - a.observation["dynamic_obstacles"][:, None],
        atol=1e-9,
    )
    with pytest.raises(deck_sim.SceneSpecError, match="predicted_frame"):
        deck_sim.load("deck1", episode__predicted_frame="target")


def test_agent_frame_turns_the_observation_and_the_action_into_the_agents_axes():
    from deck_sim.geometry import world_to_agent

    kw = {"seed": 4, "episode__obstacle_shape": True, "episode__mover_size": True, "episode__route_steps": 4}
    world = deck_sim.load("deck1", **kw)
    agent = deck_sim.load("deck1", episode__frame="agent", **kw)
    assert world.observation_spec() == agent.observation_spec()
    w, a = world.reset(), agent.reset()
    start = world.task.last_info["position"].copy()
    for step in range(12):
        ow, oa = w.observation, a.observation
        yaw = float(np.arctan2(ow["heading"][1], ow["heading"][0]))
        for key in ow:
            if key in ("position", "heading", "dynamic_size"):
                np.testing.assert_allclose(oa[key], ow[key], atol=1e-9, err_msg=key)
            else:  # every vector turned by minus the yaw, lengths kept
                np.testing.assert_allclose(oa[key], world_to_agent(ow[key], yaw), atol=1e-9, err_msg=key)
        # ahead and to one side, asked for in each env's own axes (the world one turned by hand)
        x, y = 0.9, 0.3 * (-1) ** (step // 4)
        c, s = np.cos(yaw), np.sin(yaw)
        w = world.step(np.clip(np.array([c * x - s * y, s * x + c * y]), -1.0, 1.0))
        a = agent.step(np.array([x, y]))
        np.testing.assert_allclose(agent.task.last_info["position"], world.task.last_info["position"], atol=1e-6)
    moved = agent.task.last_info["position"] - start
    assert np.linalg.norm(moved) > 5.0  # it drove; an aircraft does not slide sideways: its velocity is ahead
    assert a.observation["velocity"][0] > 1.0 and abs(a.observation["velocity"][1]) < 0.2 * a.observation["velocity"][0]
    # a planner's world action, turned into the agent's axes
    yaw = agent.task.last_info["heading"]
    np.testing.assert_allclose(agent.task.action_from_world(np.array([0.0, 0.8])), world_to_agent([0.0, 0.8], yaw))
    np.testing.assert_array_equal(world.task.action_from_world(np.array([0.0, 0.8])), [0.0, 0.8])
    with pytest.raises(deck_sim.SceneSpecError, match="frame"):
        deck_sim.load("deck1", episode__frame="body")


@pytest.mark.slow
def test_the_scripted_planner_drives_the_same_path_in_either_frame():
    from deck_sim.policies import ScriptedPolicy
    from deck_sim.rollout import run_episode

    world = deck_sim.load("deck1", seed=3, episode__predictor="constant_velocity")
    agent = deck_sim.load("deck1", seed=3, episode__predictor="constant_velocity", episode__frame="agent")
    rw, ra = run_episode(world, ScriptedPolicy(world)), run_episode(agent, ScriptedPolicy(agent))
    assert rw.outcome == ra.outcome == "goal" and rw.steps == ra.steps
    assert ra.path_length == pytest.approx(rw.path_length, abs=1e-6)
