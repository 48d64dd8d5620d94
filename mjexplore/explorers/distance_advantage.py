"""Distance advantage (Ericson, Pedro and Jensfelt 2025, "Information Gain Is Not All You
Need"): prefer the frontier near the robot and far from the other frontiers.

When the whole building must be mapped, the information to gain is fixed and the cost is
the path: a frontier the robot passes near now and leaves behind costs a detour later, most
of all one that no other frontier is near. The rule, written from the paper's public
description, takes the candidate of greatest advantage

    advantage = ``remoteness`` * (path from it to the nearest other candidate)
                - (path from the robot to it),

that is, at ``remoteness`` 1, how much closer the robot is to it than any other candidate:
the frontiers the robot is best placed to finish now. Information gain only filters the
candidates (here: the TER's frontier nodes, which drop frontiers under ``D_gain``).

The candidates and the path from the robot are :class:`~mjexplore.explorers.pocket_nearest.
PocketNearest`'s (the TER's frontier nodes, its path window and action mask), so with
``pocket_m`` > 0 the rule stands on ``pocket_nearest``'s prior (``pocket_advantage``): a
node counts ``pocket_m`` metres farther per unit of its predicted small-pocket probability.
The paths between candidates are searched on a coarse copy of the known map's traversable
cells (:class:`~mjexplore.navigation.tour.CoarseGraph`, as the frontier-TSP explorer's).
"""

from __future__ import annotations

import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.explorers.pocket_nearest import PocketNearest
from mjexplore.navigation.tour import CoarseGraph
from mjexplore.topology.frontiers import Frontier
from mjexplore.topology.ter import PaddedTer


class DistanceAdvantage(PocketNearest):
    """The TER frontier node of greatest distance advantage (see the module docstring).

    Args:
        remoteness: Weight of a node's path to its nearest other candidate (1: the paper's
            advantage).
        isolated_m: The remoteness of a node no other candidate's path reaches, metres.
        block: Fine cells per node of the path graph between candidates.
        pocket_m: Metres added per unit of predicted small-pocket probability (0: distance
            advantage alone; 50: on ``pocket_nearest``'s prior).
        **kwargs: :class:`PocketNearest`'s other settings.
    """

    name = "distance_advantage"

    def __init__(self, remoteness: float = 1.0, isolated_m: float = 50.0, block: int = 4,
                 pocket_m: float = 0.0, **kwargs) -> None:
        if remoteness < 0 or isolated_m < 0:
            raise ValueError("remoteness and isolated_m must be >= 0")
        self.remoteness = float(remoteness)
        self.isolated_m = float(isolated_m)
        self.block = block
        super().__init__(pocket_m=pocket_m, **kwargs)
        if pocket_m:
            self.name = "pocket_advantage"

    def _costs(self, padded: PaddedTer, state: ExplorationState,
               frontiers: list[Frontier]) -> np.ndarray:
        """``pocket_nearest``'s cost of each node minus ``remoteness`` times its path to the
        nearest other valid node (metres, float32)."""
        cost = super()._costs(padded, state, frontiers)
        nodes = np.flatnonzero(self.mask)
        if len(nodes) < 2 or not self.remoteness:
            return cost
        graph = CoarseGraph(state.grid, state.costmap.traversable, self.block)
        between = graph.distance_matrix(padded.node_positions[nodes].astype(float))
        np.fill_diagonal(between, np.inf)
        remote = np.minimum(between.min(axis=1), self.isolated_m)
        cost[nodes] -= np.float32(self.remoteness) * remote.astype(np.float32)
        return cost
