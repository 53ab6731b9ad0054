"""Tests of the mover predictors and the CasADi kinematic models (no MuJoCo needed).

The golden file ``tests/data/prediction_golden.npz`` holds the MPC predictor's answers on fixed analytic
tracks (do-mpc style regression). After a deliberate change of the predictor, regenerate it with

    DECK_SIM_REGEN_GOLDEN=1 python -m pytest tests/test_prediction.py -k golden

or ``python tests/test_prediction.py --regen-golden``, and say why in the commit message.
"""

from __future__ import annotations

import logging
import os
import sys
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from deck_sim.control import models
from deck_sim.control.mpc_predictor import MPCPredictor, MPCPredictorSettings
from deck_sim.control.prediction import (
    ConstantVelocity,
    PredictionInputError,
    Predictor,
    make_predictor,
)
from deck_sim.types import ObstacleKind, ObstacleTracks

DT = 0.5
H = 10
N = 10
GOLDEN = Path(__file__).parent / "data" / "prediction_golden.npz"
WHEELED = int(ObstacleKind.WHEELED)
PEDESTRIAN = int(ObstacleKind.PEDESTRIAN)


# ----- helpers -----
def straight_track(start: np.ndarray, velocity: np.ndarray, samples: int, dt: float = DT) -> np.ndarray:
    """(samples, 2) positions of a point moving at constant ``velocity`` from ``start``."""
    t = np.arange(samples)[:, None] * dt
    return start[None, :] + t * velocity[None, :]


def unicycle_track(
    pose: tuple[float, float, float], speed: float, schedule: list[tuple[float, float, float]], dt: float = DT
) -> np.ndarray:
    """Positions every ``dt`` of a unicycle driven by ``schedule``: (duration s, accel, turn rate) pieces.

    Integrated with 1 ms Euler steps on heading and speed and the exact midpoint for position; speed >= 0.
    """
    x, y, th = pose
    v = speed
    h = 1e-3
    per_sample = round(dt / h)
    out = [(x, y)]
    k = 0
    for duration, accel, rate in schedule:
        for _ in range(round(duration / h)):
            v_new = max(v + accel * h, 0.0)
            th_mid = th + 0.5 * rate * h
            x += 0.5 * (v + v_new) * h * np.cos(th_mid)
            y += 0.5 * (v + v_new) * h * np.sin(th_mid)
            th += rate * h
            v = v_new
            k += 1
            if k % per_sample == 0:
                out.append((x, y))
    return np.array(out)


def braking_track(spot_x: float, cruise: float, decel: float, samples: int, lead: float) -> np.ndarray:
    """(samples, 2) positions on the x axis of a mover cruising at ``cruise`` that brakes at ``decel`` to stop
    exactly at ``spot_x``; it starts ``lead`` seconds before braking begins, then stands still."""
    brake_time = cruise / decel
    brake_start = spot_x - cruise**2 / (2 * decel)
    t = np.arange(samples) * DT - lead
    x = np.where(
        t < 0,
        brake_start + cruise * t,
        brake_start + cruise * np.minimum(t, brake_time) - 0.5 * decel * np.minimum(t, brake_time) ** 2,
    )
    return np.stack([x, np.zeros_like(x)], axis=1)


def windows(track: np.ndarray, history: int = H) -> list[np.ndarray]:
    """Histories a task would hand over, step by step: padded with the first sample at the start."""
    padded = np.concatenate([np.repeat(track[:, :1], history - 1, axis=1), track], axis=1)
    return [padded[:, t : t + history] for t in range(track.shape[1])]


def run(pred: Predictor, tracks: np.ndarray, kinds: np.ndarray, spots: np.ndarray) -> list:
    """Reset ``pred`` and feed it every step of ``tracks`` (n, T, 2); the list of predictions."""
    pred.reset(spots, kinds)
    return [pred.predict(ObstacleTracks(dt=DT, positions=w, kinds=kinds)) for w in windows(tracks)]


@pytest.fixture(scope="module")
def mpc_settings() -> MPCPredictorSettings:
    """Default settings; the compiled library is cached (``DECK_SIM_CACHE`` or ~/.cache/deck_sim)."""
    return MPCPredictorSettings(horizon=N, dt=DT, history=H)


@pytest.fixture()
def mpc(mpc_settings: MPCPredictorSettings) -> MPCPredictor:
    """A fresh predictor (the compiled Function is built once per process and shared)."""
    return MPCPredictor(mpc_settings)


# ----- constant velocity -----
def test_constant_velocity_exact_on_straight_track() -> None:
    track = straight_track(np.array([3.0, -2.0]), np.array([2.5, 1.0]), 30)[None]
    truth = straight_track(np.array([3.0, -2.0]), np.array([2.5, 1.0]), 30 + N)[None]
    cv = ConstantVelocity(horizon=N)
    for t, w in enumerate(windows(track)):
        if t < 4:
            continue  # the padded start is not a straight line yet
        p = cv.predict(ObstacleTracks(dt=DT, positions=w, kinds=np.array([WHEELED])))
        np.testing.assert_allclose(p.positions[0], truth[0, t + 1 : t + 1 + N], atol=1e-9)


# ----- MPC predictor: behaviour -----
@pytest.mark.parametrize("kind", [WHEELED, PEDESTRIAN])
def test_mpc_exact_on_straight_track_far_from_spots(mpc: MPCPredictor, kind: int) -> None:
    """Cruising straight at constant speed, no spot ahead: the prediction is the straight line to 1e-6 m."""
    speed = 3.0 if kind == WHEELED else 1.3
    v = speed * np.array([np.cos(0.3), np.sin(0.3)])
    start = np.array([10.0, 5.0])
    track = straight_track(start, v, 40)[None]
    truth = straight_track(start, v, 40 + N)[None]
    spots = np.array([[-80.0, 60.0], [10.0, -90.0], [-50.0, -40.0]])  # behind or far off the line of travel
    preds = run(mpc, track, np.array([kind]), spots)
    for t, p in enumerate(preds):
        if t < H:
            continue  # the padded start looks like a departure from rest
        np.testing.assert_allclose(p.positions[0], truth[0, t + 1 : t + 1 + N], atol=1e-6, rtol=0)
        assert not p.fallback.any()
    assert mpc.fallback_count == 0


def test_mpc_stopped_mover_stays_put(mpc: MPCPredictor) -> None:
    here = np.array([[12.0, -3.0], [40.0, 7.0]])
    track = np.repeat(here[:, None, :], 20, axis=1)
    spots = np.array([[12.0, -3.0], [100.0, 0.0]])
    for p in run(mpc, track, np.array([WHEELED, PEDESTRIAN]), spots):
        np.testing.assert_allclose(p.positions, np.repeat(here[:, None, :], N, axis=1), atol=1e-9)


def test_mpc_forget_resets_only_the_named_movers_memory(mpc: MPCPredictor) -> None:
    """A vehicle that left and stands elsewhere is estimated afresh; the others keep their estimates."""
    spots = np.array([[0.0, 0.0], [40.0, 0.0]])
    kinds = np.array([WHEELED, WHEELED])
    mpc.reset(spots, kinds)
    tracks = np.stack([straight_track(np.array([5.0, 1.0]), np.array([2.0, 0.0]), 20),
                       straight_track(np.array([30.0, -3.0]), np.array([-1.5, 0.5]), 20)])
    for w in windows(tracks):
        mpc.predict(ObstacleTracks(dt=DT, positions=w, kinds=kinds))
    before = mpc._mem.copy()
    assert np.any(before[0] != 0.0) and np.any(before[1] != 0.0)
    mpc.forget([0])
    np.testing.assert_array_equal(mpc._mem[0], 0.0)
    np.testing.assert_array_equal(mpc._mem[1], before[1])


def test_mpc_braking_mover_predicted_to_stop_near_its_spot(mpc: MPCPredictor) -> None:
    """A tractor braking at 1 m/s^2 towards a spot: once braking is seen, the prediction stops near the spot.

    "Seen": three samples into the braking (the estimator needs about a second to tell braking from noise).
    """
    spot_x = 60.0
    track = braking_track(spot_x, cruise=4.0, decel=1.0, samples=36, lead=8.0)[None]
    spots = np.array([[spot_x, 0.0], [spot_x + 80.0, 0.0], [0.0, 50.0]])
    preds = run(mpc, track, np.array([WHEELED]), spots)
    t_brake = round(8.0 / DT)
    checked = 0
    for t in range(t_brake + 3, t_brake + 8):
        final = preds[t].positions[0, -1]
        assert abs(final[0] - spot_x) < 0.75, (t, final)
        assert abs(final[1]) < 0.1
        steps = np.diff(preds[t].positions[0, :, 0])
        assert np.all(steps >= -1e-6) and np.all(
            np.diff(steps) <= 1e-6
        )  # slowing down all along, no reversing
        checked += 1
    assert checked == 5


def test_mpc_departing_mover_heads_for_a_spot_it_points_at(mpc: MPCPredictor) -> None:
    """Leaving a spot towards another one: the prediction accelerates along the way to it, not beyond it."""
    track = np.concatenate(
        [np.zeros((8, 2)), unicycle_track((0.0, 0.0, 0.0), 0.0, [(3.0, 1.0, 0.0)])[1:]], axis=0
    )[None]
    spots = np.array([[0.0, 0.0], [15.0, 0.0], [-40.0, 30.0]])
    preds = run(mpc, track, np.array([WHEELED]), spots)
    last = preds[-1].positions[0]
    cv = ConstantVelocity(horizon=N).predict(
        ObstacleTracks(dt=DT, positions=windows(track)[-1], kinds=np.array([WHEELED]))
    )
    assert mpc.last_info[0, 0] == 1  # the spot ahead, not the one it left
    assert abs(last[-1, 0] - 15.0) < 1.0 and abs(last[-1, 1]) < 0.1  # stops at the spot ...
    assert cv.positions[0, -1, 0] > 15.5  # ... which constant velocity drives past


def test_mpc_mover_yields_to_a_mover_standing_ahead(mpc: MPCPredictor) -> None:
    """A tractor closing on a standing tractor 15 m ahead stops behind it instead of driving through it."""
    follower = straight_track(np.array([0.0, 0.0]), np.array([3.0, 0.0]), 20)
    leader = np.repeat([[follower[-1, 0] + 15.0, 0.0]], 20, axis=0)
    spots = np.array([[-100.0, 80.0], [0.0, -90.0]])
    p = run(mpc, np.stack([follower, leader]), np.array([WHEELED, WHEELED]), spots)[-1]
    assert p.positions[0, -1, 0] < leader[-1, 0] - 5.0
    assert follower[-1, 0] + 3.0 * N * DT >= leader[-1, 0]  # constant velocity would reach it
    np.testing.assert_allclose(p.positions[1], np.repeat(leader[-1:], N, axis=0), atol=1e-9)


def test_mpc_predict_shapes_and_flags(mpc: MPCPredictor) -> None:
    track = straight_track(np.zeros(2), np.array([1.0, 0.0]), 12)
    tracks = np.stack([track, track + 5.0, track * 0.0])
    preds = run(mpc, tracks, np.array([WHEELED, PEDESTRIAN, WHEELED]), np.array([[50.0, 50.0]]))
    p = preds[-1]
    assert p.positions.shape == (3, N, 2)
    assert p.fallback.shape == (3,) and p.fallback.dtype == bool
    assert p.horizon == N
    assert mpc.last_solve_time_s > 0.0
    assert mpc.last_info.shape == (3, 8)


# ----- failures and bad input -----
def test_forced_failure_falls_back_to_constant_velocity(mpc: MPCPredictor, monkeypatch, caplog) -> None:
    track = straight_track(np.zeros(2), np.array([2.0, 1.0]), 20)
    tracks = np.stack([track, track[::-1] + 3.0])
    kinds = np.array([WHEELED, WHEELED])
    mpc.reset(np.array([[100.0, 0.0]]), kinds)
    original = mpc._evaluate

    def broken(hist, kinds_, mem, force):
        pred, mem_new, info = original(hist, kinds_, mem, force)
        pred[1, 3] = np.nan  # the solve "failed" for mover 1
        return pred, mem_new, info

    monkeypatch.setattr(mpc, "_evaluate", broken)
    cv = ConstantVelocity(horizon=N)
    with caplog.at_level(logging.DEBUG, logger="deck_sim.control.mpc_predictor"):
        for count, w in enumerate(windows(tracks)[-3:], start=1):
            tk = ObstacleTracks(dt=DT, positions=w, kinds=kinds)
            p = mpc.predict(tk)
            assert p.fallback.tolist() == [False, True]
            assert p.n_fallbacks == 1
            assert mpc.fallback_count == count
            np.testing.assert_allclose(p.positions[1], cv.predict(tk).positions[1], atol=1e-12)
            assert np.all(np.isfinite(p.positions))
    assert "fallback" in caplog.text


@pytest.mark.parametrize(
    ("positions", "dt", "message"),
    [
        (np.full((2, H, 2), np.nan), DT, "NaN"),
        (np.zeros((2, H - 1, 2)), DT, "too short"),
        (np.zeros((2, H, 3)), DT, "shape"),
        (np.zeros((H, 2)), DT, "shape"),
        (np.zeros((2, H, 2)), 0.25, "dt"),
        (np.zeros((2, H, 2)), float("nan"), "dt"),
    ],
)
def test_malformed_histories_raise(mpc: MPCPredictor, positions: np.ndarray, dt: float, message: str) -> None:
    mpc.reset(np.zeros((1, 2)), np.zeros(2))
    with pytest.raises(PredictionInputError, match=message):
        mpc.predict(ObstacleTracks(dt=dt, positions=positions, kinds=np.zeros(2, dtype=int)))


def test_one_nan_names_the_obstacle(mpc: MPCPredictor) -> None:
    pos = np.zeros((3, H, 2))
    pos[2, 4, 1] = np.inf
    with pytest.raises(PredictionInputError, match=r"\[2\]"):
        mpc.predict(ObstacleTracks(dt=DT, positions=pos, kinds=np.zeros(3, dtype=int)))


@pytest.mark.parametrize("spots", [np.zeros((3, 3)), np.array([[0.0, np.nan]]), np.zeros((17, 2))])
def test_bad_spots_raise(mpc: MPCPredictor, spots: np.ndarray) -> None:
    with pytest.raises(PredictionInputError):
        mpc.reset(spots, np.zeros(2))


def test_invalid_settings_raise() -> None:
    with pytest.raises(ValueError, match="estimation_window"):
        MPCPredictorSettings(history=4, estimation_window=5)
    with pytest.raises(ValueError, match="compile"):
        MPCPredictorSettings(compile="sometimes")


# ----- construction, backends, determinism -----
def test_make_predictor_mpc() -> None:
    p = make_predictor("mpc", horizon=6, dt=DT)
    assert isinstance(p, MPCPredictor) and isinstance(p, Predictor)
    assert p.name == "mpc" and p.horizon == 6 and p.needs_future is False
    p.reset(np.array([[0.0, 0.0]]), np.array([WHEELED]))
    out = p.predict(ObstacleTracks(dt=DT, positions=np.zeros((1, H, 2)), kinds=np.array([WHEELED])))
    assert out.positions.shape == (1, 6, 2)


def test_mpc_is_deterministic(mpc_settings: MPCPredictorSettings) -> None:
    tracks, kinds, spots = golden_tracks()
    a = run(MPCPredictor(mpc_settings), tracks, kinds, spots)
    b = run(MPCPredictor(mpc_settings), tracks, kinds, spots)
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa.positions, pb.positions)


def test_virtual_machine_matches_compiled(mpc_settings: MPCPredictorSettings) -> None:
    """The pure-CasADi fallback computes the same as the compiled library."""
    compiled = MPCPredictor(mpc_settings)
    vm = MPCPredictor(replace(mpc_settings, compile="none"))
    assert vm.backend == "casadi-vm"
    tracks, kinds, spots = golden_tracks()
    tracks = tracks[:, :16]
    for pa, pb in zip(run(compiled, tracks, kinds, spots), run(vm, tracks, kinds, spots), strict=True):
        np.testing.assert_allclose(pa.positions, pb.positions, atol=1e-9)


def test_missing_compiler_falls_back_or_raises(tmp_path: Path, caplog) -> None:
    base = MPCPredictorSettings(horizon=4, compiler="no-such-cc-for-deck-sim", cache_dir=str(tmp_path))
    with caplog.at_level(logging.WARNING, logger="deck_sim.control.mpc_predictor"):
        p = MPCPredictor(base)
    assert p.backend == "casadi-vm" and "virtual machine" in caplog.text
    with pytest.raises(RuntimeError, match="not found"):
        MPCPredictor(replace(base, compile="c", horizon=5))


# ----- golden-file regression -----
def golden_tracks() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed analytic tracks (6 movers, 30 samples): cruise and brake, depart, arc, walk, stand, yield."""
    samples = 30
    spots = np.array([[60.0, 0.0], [0.0, 40.0], [-30.0, -30.0], [80.0, 60.0], [20.0, -45.0]])
    cruise_brake = braking_track(60.0, cruise=3.5, decel=1.0, samples=samples, lead=10.0)
    depart = np.concatenate(
        [
            np.repeat([[0.0, 40.0]], 6, axis=0),
            unicycle_track((0.0, 40.0, -0.6), 0.0, [(3.5, 1.0, 0.0), (9.0, 0.0, 0.0)])[1:],
        ]
    )[:samples]
    arc = unicycle_track((-10.0, -10.0, 0.5), 3.0, [(5.0, 0.0, 0.0), (5.0, 0.0, 0.3), (5.0, 0.0, 0.0)])[
        :samples
    ]
    walk = unicycle_track((70.0, 40.0, 1.2), 1.3, [(8.0, 0.0, 0.0), (1.0, 0.0, -1.2), (8.0, 0.0, 0.0)])[
        :samples
    ]
    stand = np.repeat([[20.0, -45.0]], samples, axis=0)
    yield_ = unicycle_track(
        (-60.0, 10.0, 0.0), 4.0, [(4.0, 0.0, 0.0), (3.0, -1.2, 0.0), (3.6, 1.0, 0.0), (6.0, 0.0, 0.0)]
    )
    tracks = np.stack([cruise_brake, depart, arc, walk, stand, yield_[:samples]])
    kinds = np.array([WHEELED, WHEELED, WHEELED, PEDESTRIAN, WHEELED, WHEELED])
    return tracks, kinds, spots


def golden_answers(settings: MPCPredictorSettings) -> dict[str, np.ndarray]:
    """The golden file's content: each step's predictions, fallbacks and chosen spots on ``golden_tracks``."""
    tracks, kinds, spots = golden_tracks()
    pred = MPCPredictor(settings)
    preds = run(pred, tracks, kinds, spots)
    pred.reset(spots, kinds)
    chosen = []
    for w in windows(tracks):
        pred.predict(ObstacleTracks(dt=DT, positions=w, kinds=kinds))
        chosen.append(pred.last_info[:, 0].copy())
    return {
        "positions": np.stack([p.positions for p in preds]),
        "fallback": np.stack([p.fallback for p in preds]),
        "chosen_spot": np.stack(chosen),
    }


def regenerate_golden(path: Path = GOLDEN) -> None:
    """Write the golden file from the current predictor with default settings (see the module docstring)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **golden_answers(MPCPredictorSettings(horizon=N, dt=DT, history=H)))


def test_golden_regression(mpc_settings: MPCPredictorSettings) -> None:
    if os.environ.get("DECK_SIM_REGEN_GOLDEN") == "1":
        regenerate_golden()
    if not GOLDEN.exists():
        pytest.fail(f"{GOLDEN} is missing; regenerate it (see this module's docstring)")
    want = np.load(GOLDEN)
    got = golden_answers(mpc_settings)
    np.testing.assert_array_equal(got["chosen_spot"], want["chosen_spot"])
    np.testing.assert_array_equal(got["fallback"], want["fallback"])
    np.testing.assert_allclose(got["positions"], want["positions"], atol=1e-6, rtol=0)


# ----- property: straight lines are exact for any speed and heading -----
@settings(max_examples=25, deadline=None)
@given(
    speed=st.floats(0.8, 6.0),
    heading=st.floats(-np.pi, np.pi),
    x0=st.floats(-100.0, 100.0),
    y0=st.floats(-100.0, 100.0),
)
def test_mpc_exact_on_any_straight_track_without_spots(
    speed: float, heading: float, x0: float, y0: float
) -> None:
    pred = MPCPredictor(MPCPredictorSettings(horizon=N, dt=DT, history=H))
    v = speed * np.array([np.cos(heading), np.sin(heading)])
    track = straight_track(np.array([x0, y0]), v, 2 * H + 1)[None]
    truth = straight_track(np.array([x0, y0]), v, 2 * H + 1 + N)[None]
    preds = run(pred, track, np.array([WHEELED]), np.zeros((0, 2)))
    t = 2 * H
    np.testing.assert_allclose(preds[t].positions[0], truth[0, t + 1 : t + 1 + N], atol=1e-6, rtol=0)


# ----- kinematic models -----
def test_unicycle_arc_and_limits() -> None:
    f = models.unicycle(np.pi / 0.5 / 60, substeps=10)
    x = np.array([0.0, 0.0, 0.0, 2.0])
    for _ in range(60):
        x = np.array(f(x, [0.0, 0.5])).ravel()
    # half a circle of radius v / w = 4 m at constant speed
    np.testing.assert_allclose(x[:3], [0.0, 8.0, np.pi], atol=1e-6)
    lim = models.UnicycleLimits(max_speed=3.0, max_accel=1.0, max_decel=1.0, max_turn_rate=0.6)
    g = models.unicycle(1.0, lim)
    out = np.array(g([0.0, 0.0, 0.0, 2.9], [5.0, 2.0])).ravel()
    assert out[3] == pytest.approx(3.0) and out[2] == pytest.approx(0.6)
    out = np.array(g([0.0, 0.0, 0.0, 0.5], [-5.0, 0.0])).ravel()
    assert out[3] == pytest.approx(0.0, abs=1e-12) and out[0] >= 0.0  # brakes to a stop, never reverses
    free = models.unicycle(1.0, lim, saturate=False)
    assert np.array(free([0.0, 0.0, 0.0, 2.9], [5.0, 2.0])).ravel()[3] == pytest.approx(7.9)


def test_holonomic_point_and_bicycle() -> None:
    f = models.holonomic_point(0.5, models.PointLimits(max_speed=1.5, max_accel=1.0))
    x = np.array(f([0.0, 0.0, 1.0, 0.0], [3.0, 4.0])).ravel()
    np.testing.assert_allclose(x[2:], [1.3, 0.4], atol=1e-12)  # accel scaled to 1 m/s^2 along (0.6, 0.8)
    x = np.array(f([0.0, 0.0, 1.5, 0.0], [1.0, 0.0])).ravel()
    assert np.hypot(x[2], x[3]) == pytest.approx(1.5)
    par = models.BicycleParams(wheelbase=5.0)
    b = models.kinematic_bicycle(0.01, par)
    x = np.array([0.0, 0.0, 0.0, 2.0])
    x1 = np.array(b(x, [0.0, 0.3])).ravel()
    assert (x1[2] - x[2]) / 0.01 == pytest.approx(2.0 * np.tan(0.3) / 5.0, rel=1e-9)
    assert np.array(b(x, [0.0, 3.0])).ravel()[2] / 0.01 == pytest.approx(2.0 * np.tan(par.max_steer) / 5.0)
    with pytest.raises(ValueError, match="wheelbase"):
        models.kinematic_bicycle(0.1, models.BicycleParams(wheelbase=0.0))
    with pytest.raises(ValueError, match="dt"):
        models.unicycle(0.0)
    assert isinstance(b, ca.Function) and b.name() == "kinematic_bicycle"


if __name__ == "__main__":
    if "--regen-golden" in sys.argv[1:]:
        regenerate_golden()
        print(f"wrote {GOLDEN}")
    else:
        print(__doc__)
