"""Task registry, dm_control suite style: ``TASKS`` maps a scene name to its factory."""

from __future__ import annotations

from typing import Any

from deck_sim.scenes import scene_names


def _factory(name: str):  # noqa: ANN202
    def make(seed: int | None = None, **kwargs: Any):  # noqa: ANN202 - returns composer.Environment
        from deck_sim.environment import load

        return load(name, seed=seed, **kwargs)

    make.__doc__ = f"Make the {name!r} environment: ``seed``, ``predictor`` and scene overrides as in load()."
    return make


TASKS = {name: _factory(name) for name in scene_names()}
"""Scene name -> ``factory(seed=..., predictor=..., **overrides)`` returning a composer environment."""
