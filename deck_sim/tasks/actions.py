"""The action of one control step: two real numbers in [-1, 1], checked before any actuator is set."""

from __future__ import annotations

import math
import reprlib
from typing import Any

import numpy as np


class InvalidActionError(ValueError):
    """An action is not a finite pair of real numbers in [-1, 1]."""


_REAL_KINDS = "fiu"  # numpy dtype kinds of real numbers: float, signed and unsigned integer


def _real_action(action: Any) -> np.ndarray:
    """``action`` as a float64 array if it holds real numbers only: an array of a float or integer dtype, or a
    sequence of Python or numpy floats and ints. ``InvalidActionError`` naming what it holds otherwise: booleans,
    complex numbers, strings, ``None``, mappings, integers too large for any numpy type, ragged nestings."""
    if isinstance(action, np.ndarray):  # what policies give: one dtype check
        if action.dtype.kind not in _REAL_KINDS:
            raise InvalidActionError(
                f"action must hold real numbers (a float or integer dtype), got an array of dtype {action.dtype}"
            )
        return np.asarray(action, dtype=np.float64)
    try:
        array = np.asarray(action)
    except (ValueError, TypeError, OverflowError) as err:
        raise InvalidActionError(f"action must be two real numbers, got {_shown(action)} ({err})") from None
    real = array.dtype.kind in _REAL_KINDS
    if real and isinstance(action, list | tuple) and array.shape == (2,):
        # numpy turns [True, 0.5] into floats: each element must be a real number itself
        real = all(type(x) is float or type(x) is int or np.asarray(x).dtype.kind in _REAL_KINDS for x in action)
    if not real:
        if array.dtype.kind == "O" and array.size and all(type(x) is int for x in array.flat):
            raise InvalidActionError(
                f"action must lie in [-1, 1]^2, got {_shown(action)} (integers beyond any numpy type)"
            )
        raise InvalidActionError(f"action must be two real numbers (float or int), got {_shown(action)}")
    return np.asarray(action, dtype=np.float64)


def _shown(value: Any) -> str:
    """``value``'s type and a shortened repr, for messages."""
    return f"{type(value).__name__} {reprlib.repr(value)}"


def checked_action(action: Any) -> tuple[float, float]:
    """``action`` as two plain floats if it is a pair of finite real numbers in [-1, 1] (a tolerance of 1e-6 for
    rounding); ``InvalidActionError`` naming what is wrong otherwise."""
    array = _real_action(action)
    if array.shape != (2,):
        raise InvalidActionError(f"action must have shape (2,), got {array.shape}")
    a0, a1 = array.tolist()  # (plain floats: numpy's calls on two numbers cost more than the checks)
    if not (math.isfinite(a0) and math.isfinite(a1)):
        raise InvalidActionError(f"action must be finite, got {array.tolist()}")
    if abs(a0) > 1.0 + 1e-6 or abs(a1) > 1.0 + 1e-6:
        raise InvalidActionError(f"action must lie in [-1, 1]^2, got {array.tolist()}")
    return a0, a1
