"""Symbolic helpers shared by the MPC predictor's graph stages (``casadi.SX``)."""

from __future__ import annotations

import casadi as ca


def wrap_angle(a: ca.SX) -> ca.SX:
    """Angle wrapped into (-pi, pi]."""
    return ca.atan2(ca.sin(a), ca.cos(a))


def select(cond: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """``a`` where ``cond`` else ``b`` (both evaluated)."""
    return ca.if_else(cond, a, b)
