"""dm_control composer entities of deck_sim: vehicles, static props and arenas."""

from deck_sim.entities.aircraft import Aircraft
from deck_sim.entities.arenas import DeckArena, SquareArena, make_arena
from deck_sim.entities.pedestrian import Pedestrian
from deck_sim.entities.props import StaticProp
from deck_sim.entities.tractor import Tractor

__all__ = ["Aircraft", "DeckArena", "Pedestrian", "SquareArena", "StaticProp", "Tractor", "make_arena"]
