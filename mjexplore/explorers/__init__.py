"""Exploration strategies behind one interface: state in, goal out."""

from mjexplore.explorers.base import EXPLORERS, ExplorationState, Explorer, make_explorer

__all__ = ["EXPLORERS", "ExplorationState", "Explorer", "make_explorer"]
