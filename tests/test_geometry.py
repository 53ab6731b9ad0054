"""Property tests of the planar geometry: footprint distances and visibility-graph paths."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from deck_sim.geometry import (
    Footprints,
    NoPathError,
    VisibilityGraph,
    clip_length,
    end_circles,
    points_along,
    polyline_length,
)

coord = st.floats(-50, 50, allow_nan=False)
size = st.floats(0.1, 10, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)


def box(cx, cy, hx, hy, yaw=0.0, r=0.0) -> Footprints:
    return Footprints(np.array([[cx, cy]]), np.array([[hx, hy]]), np.array([yaw]), np.array([r]))


@given(cx=coord, cy=coord, r=size, px=coord, py=coord)
def test_circle_distance_is_centre_distance_minus_radius(cx, cy, r, px, py):
    fp = Footprints(np.array([[cx, cy]]), np.zeros((1, 2)), np.zeros(1), np.array([r]))
    d = fp.distance(np.array([px, py]))[0, 0]
    assert d == pytest.approx(np.hypot(px - cx, py - cy) - r, abs=1e-9)


@given(hx=size, hy=size, yaw=angle, t=st.floats(0, 1), side=st.integers(0, 3))
def test_box_distance_is_zero_on_the_boundary_and_negative_inside(hx, hy, yaw, t, side):
    fp = box(3.0, -2.0, hx, hy, yaw)
    local = [
        (-hx + 2 * hx * t, hy),
        (-hx + 2 * hx * t, -hy),
        (hx, -hy + 2 * hy * t),
        (-hx, -hy + 2 * hy * t),
    ][side]
    c, s = np.cos(yaw), np.sin(yaw)
    p = np.array([3.0 + c * local[0] - s * local[1], -2.0 + s * local[0] + c * local[1]])
    assert fp.distance(p)[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert fp.distance(np.array([3.0, -2.0]))[0, 0] == pytest.approx(-min(hx, hy))


@given(hx=size, hy=size, yaw=angle, r=st.floats(0, 3), px=coord, py=coord)
def test_octagon_encloses_the_rounded_box(hx, hy, yaw, r, px, py):
    fp = box(0.0, 0.0, hx, hy, yaw, r)
    normals, offsets = fp.octagons()
    inside_box = fp.distance(np.array([px, py]))[0, 0] < 0
    inside_oct = bool(np.all(normals[0] @ np.array([px, py]) < offsets[0] + 1e-9))
    assert not inside_box or inside_oct


def test_straight_path_when_nothing_is_in_the_way():
    g = VisibilityGraph(box(0, 20, 2, 2), clearance=1.0, bounds=np.array([[-50, -50], [50, 50]]))
    path = g.shortest_path(np.array([-10.0, 0.0]), np.array([10.0, 0.0]))
    np.testing.assert_allclose(path, [[-10, 0], [10, 0]])


@settings(max_examples=50, deadline=None)
@given(hx=st.floats(1, 8), hy=st.floats(1, 8), yaw=angle, clearance=st.floats(0.2, 3), y0=st.floats(-1, 1))
def test_path_around_a_box_keeps_its_clearance_and_is_no_shorter_than_straight(hx, hy, yaw, clearance, y0):
    fp = box(0.0, 0.0, hx, hy, yaw)
    start, goal = np.array([-20.0, y0]), np.array([20.0, -y0])
    g = VisibilityGraph(fp, clearance=clearance, bounds=np.array([[-60, -60], [60, 60]]))
    path = g.shortest_path(start, goal)
    assert polyline_length(path) >= np.linalg.norm(goal - start) - 1e-9
    # sample the path densely: every point keeps the clearance (up to the octagon's over-approximation)
    pts = np.concatenate([np.linspace(a, b, 60) for a, b in zip(path[:-1], path[1:], strict=True)])
    assert fp.distance(pts).min() >= clearance - 1e-6


def test_known_layout_shortest_path_length():
    # a wall 0.2 m thick from y = -5 to 5 across the straight line: the way round passes two of its corners
    wall = box(0.0, 0.0, 0.1, 5.0)
    g = VisibilityGraph(wall, clearance=0.0, bounds=np.array([[-50, -50], [50, 50]]), node_margin=1e-6)
    path = g.shortest_path(np.array([-5.0, 0.0]), np.array([5.0, 0.0]))
    assert polyline_length(path) == pytest.approx(2 * np.hypot(4.9, 5.0) + 0.2, abs=1e-3)


def test_start_inside_an_obstacle_may_only_leave_it():
    fp = box(0.0, 0.0, 3.0, 3.0)
    g = VisibilityGraph(fp, clearance=2.0, bounds=np.array([[-50, -50], [50, 50]]))
    start = np.array([-4.5, 0.0])  # inside the grown box (edge at -5), on its left side
    path = g.shortest_path(start, np.array([20.0, 0.0]))
    first = path[1] - path[0]
    assert first @ (start - fp.centers[0]) > 0  # heads away from the centre, not through the box
    assert len(path) > 2


def test_unreachable_goal_raises():
    ring = Footprints.concatenate([box(0, 6, 6, 1), box(0, -6, 6, 1), box(6, 0, 1, 6), box(-6, 0, 1, 6)])
    g = VisibilityGraph(ring, clearance=0.5, bounds=np.array([[-50, -50], [50, 50]]))
    with pytest.raises(NoPathError):
        g.shortest_path(np.array([20.0, 20.0]), np.array([0.0, 0.0]))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_enclosing_disc_prefilter_gives_the_exact_segment_test(seed):
    from deck_sim.geometry import segments_blocked

    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 25))
    fp = Footprints(
        rng.uniform(-40, 40, (k, 2)), rng.uniform(0.1, 8, (k, 2)), rng.uniform(-3, 3, k), rng.uniform(0, 2, k)
    )
    grown = fp.inflate(float(rng.uniform(0, 3)))
    normals, offsets = grown.octagons()
    radii = np.linalg.norm(grown.octagon_vertices() - grown.centers[:, None], axis=2).max(axis=1)
    a = rng.uniform(-50, 50, (120, 2))
    b = a + rng.normal(0, 25, (120, 2))
    b[:4] = a[:4]  # zero-length segments
    exact = segments_blocked(a, b, normals, offsets)
    assume(exact.any() and not exact.all())  # a layout that blocks no segment, or every one, tells nothing
    np.testing.assert_array_equal(segments_blocked(a, b, normals, offsets, bounds=(grown.centers, radii)), exact)


@settings(max_examples=80, deadline=None)
@given(cx=coord, cy=coord, hx=size, hy=size, yaw=angle, r=st.floats(0, 3), px=coord, py=coord)
def test_the_nearest_boundary_point_lies_at_the_footprints_distance(cx, cy, hx, hy, yaw, r, px, py):
    fp = box(cx, cy, hx, hy, yaw, r)
    p = np.array([px, py])
    q = fp.nearest_points(p)[0]
    d = fp.distance(p)[0, 0]
    if d > 1e-9:
        assert np.linalg.norm(q - p) == pytest.approx(d, rel=1e-6, abs=1e-6)
        assert fp.distance(q)[0, 0] == pytest.approx(0.0, abs=1e-6)
    else:
        np.testing.assert_allclose(q, p, atol=1e-9)


def test_a_graph_that_has_planned_to_a_goal_before_plans_the_same_paths():
    """The per-goal cache of nodes that see the goal changes no path: every query on one reused graph equals the
    same query on a fresh graph, across goals inside and outside the grown obstacles."""
    rng = np.random.default_rng(3)
    fp = Footprints(
        rng.uniform(-30, 30, (8, 2)), rng.uniform(1, 5, (8, 2)), rng.uniform(-np.pi, np.pi, 8), rng.uniform(0, 1, 8)
    )
    bounds = np.array([[-50.0, -50.0], [50.0, 50.0]])
    reused = VisibilityGraph(fp, clearance=1.5, bounds=bounds)
    goals = [rng.uniform(-40, 40, 2) for _ in range(3)] + [fp.centers[0].copy()]  # the last inside an obstacle
    for _ in range(30):
        start, goal = rng.uniform(-40, 40, 2), goals[int(rng.integers(len(goals)))]
        try:
            expected = VisibilityGraph(fp, clearance=1.5, bounds=bounds).shortest_path(start, goal)
        except NoPathError:
            with pytest.raises(NoPathError):
                reused.shortest_path(start, goal)
            continue
        np.testing.assert_array_equal(reused.shortest_path(start, goal), expected)


@given(
    st.floats(-10.0, 10.0),
    st.lists(st.floats(-50.0, 50.0), min_size=2, max_size=2),
)
def test_agent_axes_turn_vectors_and_back_keeping_their_length(yaw, xy):
    from deck_sim.geometry import agent_to_world, world_to_agent

    v = np.array(xy)
    local = world_to_agent(v, yaw)
    np.testing.assert_allclose(np.linalg.norm(local), np.linalg.norm(v), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(agent_to_world(local, yaw), v, atol=1e-12)
    # the heading itself is straight ahead, the direction 90 degrees to its left is +y
    np.testing.assert_allclose(world_to_agent(np.array([np.cos(yaw), np.sin(yaw)]), yaw), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(world_to_agent(np.array([-np.sin(yaw), np.cos(yaw)]), yaw), [0.0, 1.0], atol=1e-12)
    # rows of an (n, k, 2) array turn alike
    stack = np.tile(v, (3, 4, 1))
    np.testing.assert_allclose(world_to_agent(stack, yaw), np.tile(local, (3, 4, 1)), atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=2, max_size=6),
    st.lists(st.floats(-10, 400), min_size=1, max_size=8),
)
def test_points_along_lie_on_the_polyline_at_their_arc_length(vertices, distances):
    path = np.array(vertices)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assume(np.all(seg > 1e-3))
    points = points_along(path, np.array(distances))
    total = polyline_length(path)
    for d, p in zip(distances, points, strict=True):
        d = min(max(d, 0.0), total)  # clamped to the ends
        k = min(int(np.searchsorted(np.cumsum(seg), d)), len(seg) - 1)  # the segment holding arc length d
        start = float(np.sum(seg[:k]))
        expected = path[k] + (path[k + 1] - path[k]) * (d - start) / seg[k]
        np.testing.assert_allclose(p, expected, atol=1e-6)


@given(
    st.lists(st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)), min_size=1, max_size=8),
    st.floats(1e-3, 50.0),
)
def test_clip_length_caps_each_vector_keeping_its_direction(vectors, max_length):
    v = np.array(vectors)
    out = clip_length(v, max_length)
    length, clipped = np.linalg.norm(v, axis=1), np.linalg.norm(out, axis=1)
    assert np.all(clipped <= max_length * (1 + 1e-12))
    short = length <= max_length
    np.testing.assert_array_equal(out[short], v[short])  # inside the range: untouched
    np.testing.assert_allclose(clipped[~short], max_length, rtol=1e-9)  # outside: on the range's circle...
    cross = v[:, 0] * out[:, 1] - v[:, 1] * out[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-9 * max(1.0, float(length.max())))  # ...along the same line
    assert np.all(np.einsum("ij,ij->i", v, out) >= 0.0)  # ...pointing the same way
    assert clip_length(v[None], max_length).shape == (1, *v.shape)  # any leading shape


def test_end_circles_of_the_aircraft_are_its_nose_and_tail():
    from deck_sim.entities.aircraft import Aircraft

    circles = end_circles(Aircraft().parts, 7.0)  # the deck agent's disc: half the wing span
    # the fuselage capsule's two ends (8.25 m half-length, 0.9 m thick) and the tail plane's tips
    np.testing.assert_allclose(circles, [[8.2, 0.0, 0.9], [-8.3, 0.0, 0.9], [-7.4, 2.6, 1.2], [-7.4, -2.6, 1.2]])
    assert end_circles(Aircraft().parts, 20.0).shape == (0, 3)  # a disc that holds the whole body needs none


@given(
    part=st.tuples(
        st.floats(-5, 5), st.floats(-5, 5), st.floats(0, 8), st.floats(0, 8), st.floats(0, 2)
    ),
    radius=st.floats(0.5, 12),
)
def test_end_circles_cover_every_end_outside_the_disc(part, radius):
    cx, cy, hx, hy, r = part
    circles = end_circles(np.array([part]), radius)
    along = np.array([hx, 0.0]) if hx >= hy else np.array([0.0, hy])
    ends = [np.array([cx, cy]) + along, np.array([cx, cy]) - along]
    outside = [e for e in ends if np.hypot(*e) > radius]
    assert len(circles) == len(outside)
    for e, c in zip(outside, circles, strict=True):
        np.testing.assert_allclose(c[:2], e)
        assert c[2] == pytest.approx(min(hx, hy) + r)  # as wide as the part
        assert np.hypot(*c[:2]) > radius
