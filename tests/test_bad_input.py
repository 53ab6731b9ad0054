"""Bad input at each entry point gets the project's own error naming the field or file, and the command line exits 2
with one line: actions (``InvalidActionError``), the Gymnasium env's step order (``ResetNeeded``), actor files
(``PolicyFileError``), episode logs (``LogError``; a damaged summary section is read past and ``recover`` rebuilds
it), the sizes, names and counts of ``deck-sim render`` and ``log video``, the folder of ``deck-sim run`` and its
Ctrl-C. Property tests (hypothesis, the deterministic profile of conftest.py) throw generated junk at each."""


import numpy as np
import pytest
from conftest import NEAR
from gymnasium.error import ResetNeeded
from hypothesis import given, settings
from hypothesis import strategies as st

import deck_sim
from deck_sim.tasks.navigate import InvalidActionError, _real_action
from deck_sim.wrappers import DeckSimEnv


# -- fixtures ------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env():
    """One deck 1 environment for the whole module, reset once: bad actions never change it."""
    e = deck_sim.load("deck1", seed=0)
    e.reset()
    return e


# -- actions -------------------------------------------------------------------------------------------------------
BAD_ACTIONS = [
    (["0.5", "0.5"], "real numbers"),
    ([True, False], "real numbers"),
    ([0.5 + 3j, 0], "real numbers"),
    (["a", "b"], "real numbers"),
    ({"x": 1}, "real numbers"),
    (None, "real numbers"),
    ([True, 0.5], "real numbers"),
    ([None, 0.5], "real numbers"),
    ([[1], [2, 3]], "real numbers"),
    (np.array([True, False]), "dtype bool"),
    (np.array([0.5, 0.5], dtype=complex), "dtype complex128"),
    (np.array(["0.5", "0.5"]), "dtype <U3"),
    (np.array([0.5, 0.5], dtype=object), "dtype object"),
    ([10**400, 0], r"\[-1, 1\]"),
    ([1.5, 0.0], r"\[-1, 1\]"),
    ([np.nan, 0.0], "finite"),
    ([0.0, -np.inf], "finite"),
    (np.zeros(3), "shape"),
    ([[0.1, 0.2]], "shape"),
    (0.5, "shape"),
]


@pytest.mark.parametrize(("action", "match"), BAD_ACTIONS, ids=[repr(a)[:30] for a, _ in BAD_ACTIONS])
def test_a_bad_action_is_an_invalid_action_error(env, action, match):
    with pytest.raises(InvalidActionError, match=match):
        env.step(action)


def test_real_actions_of_every_numeric_type_are_read_as_before(env):
    valid = [
        np.array([0.25, -0.5]), np.array([0.25, -0.5], dtype=np.float32), np.array([0.25, -0.5], dtype=np.float16),
        np.array([0.25, -0.5], dtype=np.longdouble), np.array([1, 0]), np.array([1, 0], dtype=np.uint8),
        [0.25, -0.5], (1, 0), [np.float32(0.25), np.float64(-0.5)], [np.int64(1), 0.5], [np.float16(0.3), 1],
    ]
    for action in valid:
        got = _real_action(action)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, np.asarray(action, dtype=np.float64))
    env.step(valid[0])
    env.reset()


def _maybe_valid(action) -> bool:
    """Whether a generated action could be a valid one (two real numbers in [-1, 1])."""
    return (
        isinstance(action, list)
        and len(action) == 2
        and all(type(x) in (int, float) and abs(x) <= 1.0 for x in action)
    )


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=8,
)
_BAD_NUMBER = st.one_of(
    st.booleans(),
    st.text(max_size=4),
    st.none(),
    st.complex_numbers(max_magnitude=1.0),
    st.sampled_from([float("nan"), float("inf"), -float("inf")]),
    st.integers(min_value=2) | st.integers(max_value=-2),
    st.floats(min_value=1.001, allow_infinity=False) | st.floats(max_value=-1.001, allow_infinity=False),
    st.lists(st.floats(-1, 1), min_size=1, max_size=2),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
)
_BAD_ACTIONS = st.one_of(
    _JSON.filter(lambda a: not _maybe_valid(a)),
    st.tuples(_BAD_NUMBER, st.floats(-1, 1), st.booleans()).map(lambda t: [t[0], t[1]] if t[2] else [t[1], t[0]]),
    st.lists(st.floats(-1, 1), max_size=5).filter(lambda a: len(a) != 2),
    st.lists(st.floats(-1, 1), min_size=2, max_size=2).map(lambda a: [a]),
    st.tuples(st.sampled_from([bool, complex, str, object]), st.lists(st.floats(-1, 1), min_size=2, max_size=2)).map(
        lambda t: np.array(t[1]).astype(t[0])
    ),
)


@settings(max_examples=150, deadline=None)
@given(action=_BAD_ACTIONS)
def test_generated_bad_actions_raise_only_invalid_action_error(env, action):
    with pytest.raises(InvalidActionError):
        env.step(action)


# -- the Gymnasium environment -------------------------------------------------------------------------------------
def test_the_gym_env_steps_only_inside_an_episode():
    env = DeckSimEnv("deck1", **NEAR)
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="real numbers"):
        env.step(["0.5", "0.5"])
    terminated = truncated = False
    while not (terminated or truncated):  # straight ahead, off the deck's edge
        _, reward, terminated, truncated, _ = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert terminated and np.isfinite(reward)
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=1)
    env.step(np.zeros(2, dtype=np.float32))  # an episode again
    env.close()

    short = DeckSimEnv("deck1", episode__time_limit=1.0)
    short.reset(seed=0)
    truncated = False
    while not truncated:
        _, _, terminated, truncated, _ = short.step(np.zeros(2, dtype=np.float32))
        assert not terminated
    with pytest.raises(ResetNeeded):
        short.step(np.zeros(2, dtype=np.float32))
    short.close()
