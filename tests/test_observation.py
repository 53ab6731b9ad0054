"""The observation built from hand-made arrays (no physics): nearest-first order, relative vectors, the near field,
the agent frame, and every key's shape as ``observation_shapes`` announces it."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from deck_sim.geometry import Footprints
from deck_sim.tasks.observation import (
    TURNED_KEYS,
    ObservationConfig,
    build_observation,
    closest_approach,
    near_forecast,
    observation_shapes,
)

BOUNDS = np.array([[-20.0, -10.0], [30.0, 10.0]])
MOVER_HALF = np.array([[2.0, 1.0], [0.0, 0.0], [9.0, 6.0]])
MOVER_RADIUS = np.array([0.0, 0.3, 0.0])


def config(horizon: int = 2, **options) -> ObservationConfig:
    return ObservationConfig(horizon, BOUNDS, MOVER_HALF, MOVER_RADIUS, **options)


def squares(centres) -> Footprints:
    """Unit squares (half-extent 1 m, unrotated) at ``centres``."""
    centres = np.asarray(centres, dtype=float)
    return Footprints(centres, np.ones_like(centres), np.zeros(len(centres)), np.zeros(len(centres)))


AGENT = np.array([1.0, 2.0])
STATICS = squares([[11.0, 2.0], [1.0, 5.0], [-5.0, 2.0]])  # 10, 3 and 6 m from the agent
MOVER_XY = np.array([[1.0, -6.0], [3.0, 2.0], [1.0, 22.0]])  # 8, 2 and 20 m from the agent
MOVER_YAW = np.array([0.0, 0.5, math.pi / 2])
PREDICTED = MOVER_XY[:, None, :] + np.array([[1.0, 0.0], [2.0, 0.0]])  # each mover 1 and 2 m east of where it is


def observe(cfg: ObservationConfig, yaw: float = 0.3, route=None) -> dict[str, np.ndarray]:
    return build_observation(
        cfg, AGENT, yaw, np.array([0.5, -0.25]), np.array([4.0, 6.0]), STATICS, MOVER_XY, MOVER_YAW, PREDICTED, route
    )


def test_obstacles_come_nearest_first_as_vectors_from_the_agent():
    obs = observe(config())
    np.testing.assert_array_equal(obs["target"], [3.0, 4.0])
    np.testing.assert_array_equal(obs["static_obstacles"], [[0.0, 3.0], [-6.0, 0.0], [10.0, 0.0]])
    np.testing.assert_array_equal(obs["dynamic_obstacles"], [[2.0, 0.0], [0.0, -8.0], [0.0, 20.0]])
    # each mover's predicted positions stay with it: the rows follow the movers' order
    np.testing.assert_array_equal(obs["predicted"][:, 1], obs["dynamic_obstacles"] + [2.0, 0.0])
    np.testing.assert_array_equal(obs["position"], AGENT)
    np.testing.assert_array_equal(obs["velocity"], [0.5, -0.25])
    np.testing.assert_allclose(obs["heading"], [math.cos(0.3), math.sin(0.3)])


def test_predicted_positions_relative_to_each_mover_are_its_displacements():
    obs = observe(config(predicted_from_agent=False))
    np.testing.assert_array_equal(obs["predicted"], np.broadcast_to([[1.0, 0.0], [2.0, 0.0]], (3, 2, 2)))


def test_equal_distances_keep_the_given_order():
    statics = squares([[4.0, 2.0], [1.0, 5.0], [-2.0, 2.0]])  # all 3 m from the agent
    obs = build_observation(config(), AGENT, 0.0, np.zeros(2), AGENT, statics, MOVER_XY, MOVER_YAW, PREDICTED)
    np.testing.assert_array_equal(obs["static_obstacles"], statics.centers - AGENT)


def test_every_option_adds_its_keys_with_the_announced_shapes_in_order():
    cfg = config(
        obstacle_shape=True,
        mover_size=MOVER_HALF + MOVER_RADIUS[:, None],
        near=5.0,
        near_obstacles=True,
        route_steps=2,
        agent_frame=True,
        approach_dt=0.5,
        predicted_near=True,
    )
    obs = observe(cfg, route=np.array([[2.0, 3.0], [3.0, 4.0]]))
    shapes = observation_shapes(cfg, 3, 3)
    assert list(obs) == list(shapes)
    assert {k: v.shape for k, v in obs.items()} == shapes
    assert list(observation_shapes(config(horizon=0), 3, 3)) == [
        "target",
        "static_obstacles",
        "dynamic_obstacles",
        "position",
        "velocity",
        "heading",
    ]


def test_obstacle_shape_gives_nearest_points_headings_and_sizes_in_the_movers_order():
    obs = observe(config(obstacle_shape=True, mover_size=MOVER_HALF + MOVER_RADIUS[:, None]))
    # the squares' nearest sides: 2 m above, 5 m west, 9 m east of the agent
    np.testing.assert_allclose(obs["static_nearest"], [[0.0, 2.0], [-5.0, 0.0], [9.0, 0.0]])
    # nearest first: the 0.3 m disc 2 m east, the 2 x 1 box 8 m south (its top edge 7 m away), the aircraft north
    np.testing.assert_allclose(obs["dynamic_nearest"], [[1.7, 0.0], [0.0, -7.0], [0.0, 11.0]], atol=1e-12)
    np.testing.assert_allclose(
        obs["dynamic_heading"], [[math.cos(0.5), math.sin(0.5)], [1.0, 0.0], [0.0, 1.0]], atol=1e-12
    )
    np.testing.assert_array_equal(obs["dynamic_size"], [[0.3, 0.3], [2.0, 1.0], [9.0, 6.0]])


def test_the_near_field_clips_the_target_the_edges_and_the_obstacles():
    obs = observe(config(near=2.5, near_obstacles=True, obstacle_shape=True))
    np.testing.assert_allclose(obs["target_near"], [1.5, 2.0])  # (3, 4) clipped to 2.5 m
    # west, east, south, north edges: 21, 29, 12 and 8 m away, each clipped to 2.5 m
    np.testing.assert_array_equal(obs["edge_near"], [2.5, 2.5, 2.5, 2.5])
    near_edges = build_observation(
        config(near=10.0), np.array([-15.0, 9.0]), 0.0, np.zeros(2), AGENT, STATICS, MOVER_XY, MOVER_YAW, PREDICTED
    )
    np.testing.assert_array_equal(near_edges["edge_near"], [5.0, 10.0, 10.0, 1.0])
    np.testing.assert_allclose(obs["static_near"], [[0.0, 2.0], [-2.5, 0.0], [2.5, 0.0]])
    np.testing.assert_allclose(obs["dynamic_near"], [[1.7, 0.0], [0.0, -2.5], [0.0, 2.5]], atol=1e-12)


def test_route_points_are_relative_to_the_agent():
    obs = observe(config(route_steps=2), route=np.array([[2.0, 3.0], [4.0, 6.0]]))
    np.testing.assert_array_equal(obs["route"], [[1.0, 1.0], [3.0, 4.0]])


def test_the_agent_frame_turns_the_relative_vectors_only():
    world = observe(config(obstacle_shape=True, near=5.0, near_obstacles=True), yaw=math.pi / 2)
    agent = observe(config(obstacle_shape=True, near=5.0, near_obstacles=True, agent_frame=True), yaw=math.pi / 2)
    assert list(agent) == list(world)
    # heading north: the target 3 m east and 4 m north is 4 m ahead and 3 m to the right
    np.testing.assert_allclose(agent["target"], [4.0, -3.0], atol=1e-12)
    for key in world:
        if key in TURNED_KEYS:
            turned = np.stack([world[key][..., 1], -world[key][..., 0]], axis=-1)
            np.testing.assert_allclose(agent[key], turned, atol=1e-12, err_msg=key)
        else:
            np.testing.assert_array_equal(agent[key], world[key], err_msg=key)


point = st.tuples(st.floats(-40, 40), st.floats(-40, 40))


@given(
    agent=point,
    statics=st.lists(point, min_size=1, max_size=8),
    movers=st.lists(point, min_size=3, max_size=3),
    yaw=st.floats(-math.pi, math.pi),
)
def test_any_layout_gives_every_obstacle_once_nearest_first(agent, statics, movers, yaw):
    agent_xy = np.array(agent)
    mover_xy = np.array(movers)
    fp = squares(statics)
    obs = build_observation(
        config(agent_frame=True), agent_xy, yaw, np.zeros(2), agent_xy, fp, mover_xy, MOVER_YAW, PREDICTED
    )
    for key, centres in (("static_obstacles", fp.centers), ("dynamic_obstacles", mover_xy)):
        rel = centres - agent_xy
        got = obs[key]
        lengths = np.hypot(got[:, 0], got[:, 1])
        assert np.all(np.diff(lengths) >= -1e-9)  # nearest first (turning keeps lengths to rounding)
        back = got @ np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]])  # to the world
        order = np.einsum("ij,ij->i", rel, rel).argsort(kind="stable")
        np.testing.assert_allclose(back, rel[order], atol=1e-9)
    np.testing.assert_allclose(obs["target"], [0.0, 0.0])


@pytest.mark.parametrize("horizon", [0, 3])
def test_the_predicted_key_follows_the_horizon(horizon):
    cfg = config(horizon)
    predicted = np.zeros((3, horizon, 2))
    obs = build_observation(cfg, AGENT, 0.0, np.zeros(2), AGENT, STATICS, MOVER_XY, MOVER_YAW, predicted)
    assert ("predicted" in obs) == (horizon > 0)
    assert {k: v.shape for k, v in obs.items()} == observation_shapes(cfg, 3, 3)


def test_the_closest_approach_of_each_mover_is_read_from_its_forecast_in_the_movers_order():
    # the agent drives east at 0.5 m/s (and south at 0.25); every mover's forecast goes 1 and 2 m east of it
    obs = observe(config(approach_dt=0.5))
    velocity = np.array([0.5, -0.25])
    for row, now in enumerate(obs["dynamic_obstacles"]):  # nearest first, as ``dynamic_obstacles``
        track = [now, now + [1.0, 0.0] - 0.5 * velocity, now + [2.0, 0.0] - 1.0 * velocity]
        dist = [float(np.hypot(*p)) for p in track]
        k = int(np.argmin(dist))
        np.testing.assert_allclose(obs["predicted_approach"][row], [0.5 * k, dist[k]], rtol=1e-12)
    # the mover 2 m east moves away: its closest approach is now; the one 8 m south comes no nearer than now either
    assert obs["predicted_approach"][0, 0] == 0.0 and obs["predicted_approach"][0, 1] == 2.0
    assert "predicted_approach" not in observe(config())


@given(
    now=st.tuples(st.floats(-40, 40), st.floats(-40, 40)),
    speed=st.floats(0.5, 5.0),
    steps=st.integers(1, 10),
)
def test_a_mover_driving_at_a_standing_agent_is_nearest_at_the_end_of_its_forecast(now, speed, steps):
    now = np.array(now)
    gap = float(np.hypot(*now))
    if gap < speed * 0.5 * steps + 1.0:  # (it must not reach the agent within the forecast)
        return
    towards = -now / gap
    forecast = now + np.arange(1, steps + 1)[:, None] * 0.5 * speed * towards
    t, d = closest_approach(now[None], forecast[None], np.zeros(2), 0.5)[0]
    assert t == pytest.approx(0.5 * steps) and d == pytest.approx(gap - 0.5 * speed * steps)
    # standing still in its forecast, it is nearest now; and the agent's own motion counts as the mover's would
    t0, d0 = closest_approach(now[None], np.repeat(now[None, None], steps, 1), np.zeros(2), 0.5)[0]
    assert t0 == 0.0 and d0 == pytest.approx(gap)
    t2, d2 = closest_approach(now[None], np.repeat(now[None, None], steps, 1), -speed * towards, 0.5)[0]
    assert t2 == pytest.approx(t) and d2 == pytest.approx(d)


def test_the_near_forecast_carries_each_movers_nearest_point_along_its_forecast_clipped_to_the_field():
    # each mover its own motion: the box 8 m south goes 1 and 2 m east, the disc 2 m east 1 and 2 m north, the
    # aircraft 20 m north 3 and 6 m west
    steps = np.array([[[1.0, 0.0]], [[0.0, 1.0]], [[-3.0, 0.0]]]) * np.array([1.0, 2.0])[None, :, None]
    predicted = MOVER_XY[:, None, :] + steps
    cfg = config(near=5.0, near_obstacles=True, predicted_near=True)
    obs = build_observation(
        cfg, AGENT, 0.3, np.zeros(2), np.array([4.0, 6.0]), STATICS, MOVER_XY, MOVER_YAW, predicted
    )
    assert obs["predicted_near"].shape == (3, 2, 2)
    # nearest first, as ``dynamic_obstacles``: the disc of radius 0.3 at 2 m east, nearest point 1.7 m east,
    # moving north
    np.testing.assert_allclose(obs["predicted_near"][0], [[1.7, 1.0], [1.7, 2.0]], rtol=1e-12)
    # the box 8 m south (half-width 1 m: nearest point 7 m south) moved 1 and 2 m east, then clipped to 5 m
    for k, east in enumerate((1.0, 2.0)):
        v = np.array([east, -7.0])
        np.testing.assert_allclose(obs["predicted_near"][1, k], v * 5.0 / np.hypot(*v), rtol=1e-12)
    # the aircraft (nearest point 11 m north) moved west, clipped
    for k, west in enumerate((3.0, 6.0)):
        v = np.array([-west, 11.0])
        np.testing.assert_allclose(obs["predicted_near"][2, k], v * 5.0 / np.hypot(*v), rtol=1e-12)
    # the same rows without the near obstacles; absent without a near field or a forecast
    alone = build_observation(
        config(near=5.0, predicted_near=True), AGENT, 0.3, np.zeros(2), np.array([4.0, 6.0]), STATICS, MOVER_XY,
        MOVER_YAW, predicted,
    )
    np.testing.assert_array_equal(alone["predicted_near"], obs["predicted_near"])
    assert "dynamic_near" not in alone and "static_near" not in alone
    assert "predicted_near" not in observe(config(predicted_near=True))
    assert "predicted_near" not in observe(config(horizon=0, near=5.0, predicted_near=True))
    assert "predicted_near" not in observation_shapes(config(horizon=0, near=5.0, predicted_near=True), 3, 3)


@given(
    nearest=st.tuples(st.floats(-30, 30), st.floats(-30, 30)),
    step=st.tuples(st.floats(-3, 3), st.floats(-3, 3)),
    near=st.floats(1.0, 20.0),
    steps=st.integers(1, 6),
)
def test_a_standing_forecast_repeats_the_near_point_and_a_moving_one_keeps_its_direction(nearest, step, near, steps):
    nearest, step = np.array([nearest]), np.array(step)
    now = np.array([[5.0, -2.0]])
    standing = near_forecast(nearest, now, np.repeat(now[:, None], steps, 1), near)
    clipped = nearest * min(1.0, near / max(float(np.hypot(*nearest[0])), 1e-300))
    np.testing.assert_allclose(standing[0], np.repeat(clipped, steps, 0), rtol=1e-9, atol=1e-12)
    forecast = now[:, None] + np.arange(1, steps + 1)[:, None] * step
    moving = near_forecast(nearest, now, forecast, near)[0]
    unclipped = nearest[0] + np.arange(1, steps + 1)[:, None] * step
    length = np.hypot(unclipped[:, 0], unclipped[:, 1])
    np.testing.assert_allclose(np.hypot(moving[:, 0], moving[:, 1]), np.minimum(length, near), rtol=1e-9, atol=1e-12)
    # the direction is kept: each row is a non-negative multiple of the unclipped vector
    cross = moving[:, 0] * unclipped[:, 1] - moving[:, 1] * unclipped[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-9 * max(1.0, float(length.max())) ** 2)
    assert np.all(np.einsum("ij,ij->i", moving, unclipped) >= -1e-9)
