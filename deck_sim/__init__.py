"""deck_sim: path planning among moving obstacles on a carrier flight deck, on MuJoCo physics.

Public surface: ``load(name, seed=..., **overrides)`` returns a dm_control composer environment; ``TASKS`` lists
the scenes; the Gymnasium environments ``deck_sim/Deck1-v0``, ``deck_sim/Deck2-v0`` and ``deck_sim/Square-v0`` are
registered on import of ``deck_sim.wrappers``.
"""

from deck_sim.environment import load
from deck_sim.scenes import SceneSpecError, load_scene, scene_names
from deck_sim.tasks import TASKS

__version__ = "0.1.0"

__all__ = ["SceneSpecError", "TASKS", "__version__", "load", "load_scene", "scene_names"]
