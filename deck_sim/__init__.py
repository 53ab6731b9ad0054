"""deck_sim: path planning among moving obstacles on a carrier flight deck, on MuJoCo physics.

Public surface: ``load(name, seed=..., **overrides)`` returns a dm_control composer environment; ``TASKS`` lists
the scenes; importing ``deck_sim`` registers the Gymnasium environments ``deck_sim/Deck1-v0``, ``deck_sim/Deck2-v0``
and ``deck_sim/Square-v0`` (``gymnasium.make`` builds them on demand).

The names are resolved lazily, so that ``deck_sim.control`` (numpy and CasADi only) imports without MuJoCo.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = ["InvalidActionError", "SceneSpecError", "TASKS", "__version__", "load", "load_scene", "scene_names"]

_LAZY = {
    "load": ("deck_sim.environment", "load"),
    "TASKS": ("deck_sim.tasks", "TASKS"),
    "InvalidActionError": ("deck_sim.tasks.actions", "InvalidActionError"),
    "SceneSpecError": ("deck_sim.scenes", "SceneSpecError"),
    "load_scene": ("deck_sim.scenes", "load_scene"),
    "scene_names": ("deck_sim.scenes", "scene_names"),
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'deck_sim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


def _register() -> None:
    from deck_sim.registration import register_envs

    register_envs()


_register()
