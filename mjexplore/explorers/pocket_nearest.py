"""Pocket-aware nearest frontier: the hand-set prior of the shipped GVN (``gvn_v3``) alone.

``gvn_v3``'s actor adds its network's logits to a fixed prior
(:func:`mjexplore.policies.gvn.path_prior`): at each decision, over the TER's frontier
nodes that are not blacklisted, the prior's logit of a node is minus its cost,

    cost = path + ``pocket_m`` * pocket  (metres),

where ``path`` is the path cost from the robot over the known map to the node (the least
over the cells within ``path_radius`` of it, wall penalty included) and ``pocket`` the
probability, by the map-only predictor of :mod:`mjexplore.topology.pockets`, that the
unseen free space behind the node's frontier is small (below 0.5 m^2). A node no path
reaches counts ``EXCLUDED_M`` farther. This explorer takes the node of least cost: the
nearest frontier whose pocket is not likely small, i.e. what ``gvn_v3`` would choose with
its network's contribution removed (the argmax of the prior's logits over the masked nodes,
first node on ties).

Every number is computed as ``gvn_v3``'s observation computes it
(:class:`mjexplore.envs.decisions.TerDecisions`, v3 features), here from the
:class:`~mjexplore.episode.explorer.ExplorationState` and :mod:`mjexplore.topology` only (the
explorers sit below the envs): the same TER settings, node padding, action mask, path
window, float32 rounding and pocket predictor. The defaults are those stored in
``models/gvn_v3/policy.safetensors``.

When no TER node is a valid goal (frontiers remain that the TER cannot link), it answers
None and the episode takes the nearest frontier (counted in ``fallbacks``), as the GVN
explorer does.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.maps import GridMap
from mjexplore.topology.frontiers import Frontier
from mjexplore.topology.pipeline import TopologyConfig, TopologyTracker
from mjexplore.topology.pockets import (
    PocketPredictor,
    node_frontiers,
    pocket_areas,
    pocket_predictor,
)
from mjexplore.topology.ter import PaddedTer

# gvn_v3's settings (its weights file's stored layout and policy arguments).
GVN_V3_POCKETS = "training/pockets.safetensors"
GVN_V3_POCKETS_SHA256 = "547de234e624b30f"
GVN_V3_POCKET_M = 50.0
GVN_V3_PATH_RADIUS = 0.5
GVN_V3_MAX_NODES = 256
GVN_V3_MAX_NEIGHBOURS = 8
GVN_V3_TOPOLOGY = TopologyConfig()  # Stored in full in its layout; these are the defaults.
# As the v3 observation: node features are clipped to +-FEATURE_BOUND metres, and the prior
# counts an unreachable node 2 FEATURE_BOUND farther.
FEATURE_BOUND = 1.0e4
EXCLUDED_M = 2 * FEATURE_BOUND


class PocketNearest:
    """Nearest frontier node by path, ``pocket_m`` metres farther per unit of predicted
    small-pocket probability (see the module docstring).

    Args:
        pocket_m: Metres added to a node's path cost per unit of its pocket probability
            (``gvn_v3``'s ``prior_pocket_m``, 50 m; 0: nearest TER frontier node).
        pockets: The pocket predictor's weights file (``mjexplore train-pockets``); a
            relative path is looked up from the working directory, then from the
            repository root. None: no predictor (a subclass supplies the pockets).
        pockets_sha256: If set, the first 16 hex digits of that file's sha256 (another
            file is refused); None accepts any file. The default pins ``gvn_v3``'s.
        path_radius: A node's path cost is the least over the cells within this distance
            of it, metres.
        topology: TER settings (information gain, D_gain, link candidates); its
            ``ter.max_nodes`` and ``ter.max_neighbours`` are replaced by ``max_nodes`` and
            ``max_neighbours``. None: the episode's own (as a GVN whose layout stores no
            topology). Default: ``gvn_v3``'s (the defaults of
            :class:`~mjexplore.topology.pipeline.TopologyConfig`).
        max_nodes: N_max, TER nodes kept at a decision (robot and frontier nodes first).
        max_neighbours: K, neighbour slots per node of the padded TER.
    """

    name = "pocket_nearest"

    def __init__(self, pocket_m: float = GVN_V3_POCKET_M,
                 pockets: str | os.PathLike | None = GVN_V3_POCKETS,
                 pockets_sha256: str | None = GVN_V3_POCKETS_SHA256,
                 path_radius: float = GVN_V3_PATH_RADIUS,
                 topology: TopologyConfig | None = GVN_V3_TOPOLOGY,
                 max_nodes: int = GVN_V3_MAX_NODES,
                 max_neighbours: int = GVN_V3_MAX_NEIGHBOURS) -> None:
        if pocket_m < 0 or path_radius < 0:
            raise ValueError("pocket_m and path_radius must be >= 0 (metres)")
        if max_nodes < 2 or max_neighbours < 1:
            raise ValueError("max_nodes must be >= 2 and max_neighbours >= 1")
        self.pocket_m = float(pocket_m)
        self.path_radius = float(path_radius)
        self.topology = topology
        ter = (topology or GVN_V3_TOPOLOGY).ter
        self.ter_config = dataclasses.replace(ter, max_nodes=max_nodes,
                                              max_neighbours=max_neighbours)
        self.pockets: PocketPredictor | None = (
            pocket_predictor(pockets, pockets_sha256) if self.pocket_m and pockets else None)
        self._tracker: TopologyTracker | None = None
        self.reset(np.random.default_rng(0))

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self._tracker = None
        self.padded: PaddedTer | None = None  # The TER of the last decision...
        self.mask = np.zeros(0, bool)  # ...its valid nodes...
        self.cost = np.zeros(0, np.float32)  # ...and their costs (metres, inf: invalid).
        self.pocket_memo: dict[bytes, np.float32] = {}  # The episode's pocket predictions.

    def _tracker_of(self, state: ExplorationState) -> TopologyTracker:
        """The episode's topology tracker, or (outside an episode) one of our own brought
        up to date with the whole map."""
        tracker = state.extras.get("tracker")
        if tracker is not None:
            return tracker
        if self._tracker is None or self._tracker.gvd.shape != state.grid.shape:
            self._tracker = TopologyTracker(state.grid.shape, self.topology)
        self._tracker.observe(state.grid)
        state.extras["tracker"] = self._tracker
        return self._tracker

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        """The valid frontier node of least cost, or None when no TER node is valid.

        Args:
            state: The decision's state (the episode's tracker in ``extras``).

        Returns:
            The node's position (x, y) in the ``map`` frame, metres.
        """
        tracker = self._tracker_of(state)
        ter, frontiers, _ = tracker.ter(state.grid, state.pose, self.topology)
        state.extras["ter"] = ter
        padded = ter.padded(self.ter_config)
        mask = padded.action_mask.copy()
        if mask.any():
            mask[mask] = state.allowed(padded.node_positions[mask])
        self.padded, self.mask = padded, mask
        self.cost = np.full(len(mask), np.inf, np.float32)
        if not mask.any():
            return None
        self.cost[mask] = self._costs(padded, state, frontiers)[mask]
        node = int(np.argmin(self.cost))  # The first of equal costs, as the GVN's argmax.
        return padded.node_positions[node].astype(float)

    def _costs(self, padded: PaddedTer, state: ExplorationState,
               frontiers: list[Frontier]) -> np.ndarray:
        """(N_max,) float32 cost of each node (metres): path, ``EXCLUDED_M`` more if no
        path reaches it, ``pocket_m`` per unit of pocket probability; exact for the
        valid nodes only (blacklisted ones are not counted out)."""
        grid = state.grid
        mask = self.mask
        path = np.zeros(len(mask), np.float32)
        unreachable = np.zeros(len(mask), np.float32)
        half = int(round(self.path_radius / grid.resolution))
        cells = np.clip(grid.world_to_cell(padded.node_positions[mask]), 0,
                        np.array(grid.shape) - 1)
        nearest = state.costmap.distances_near(state.pose[:2], cells, half)
        reachable = np.isfinite(nearest)
        path[mask] = np.where(reachable, nearest, 0.0).astype(np.float32)
        unreachable[mask] = ~reachable
        path = np.clip(path, -FEATURE_BOUND, FEATURE_BOUND)
        cost = path + np.float32(EXCLUDED_M) * unreachable
        if self.pocket_m and frontiers:
            pocket = self.pocket_probability(padded, state, frontiers)
            cost = cost + np.float32(self.pocket_m) * np.clip(pocket, -FEATURE_BOUND,
                                                              FEATURE_BOUND)
        return cost.astype(np.float32)

    def pocket_probability(self, padded: PaddedTer, state: ExplorationState,
                           frontiers: list[Frontier]) -> np.ndarray:
        """(N_max,) float32: each frontier node's probability that its pocket is small, by
        the pocket predictor (0 for the other nodes)."""
        assert self.pockets is not None  # Without a predictor, a subclass supplies them.
        return self.pockets.node_probability(padded, state.grid, frontiers, self.pocket_memo)


class TruePocketNearest(PocketNearest):
    """``pocket_nearest``'s rule with the *true* pockets in place of the predicted ones: a
    frontier node counts ``pocket_m`` metres farther when the ground truth's unseen free
    space behind its frontier (:func:`~mjexplore.topology.pockets.pocket_areas`) is below
    ``small_area_m2``. Privileged (it reads the ground truth): the bound on what a perfect
    pocket predictor is worth to the rule.

    Args:
        small_area_m2: A pocket below this area counts as small, m^2 (the predictor's).
        **kwargs: :class:`PocketNearest`'s (but ``pockets``).
    """

    name = "pocket_truth"

    def __init__(self, small_area_m2: float = 0.5, **kwargs) -> None:
        self.small_area_m2 = float(small_area_m2)
        super().__init__(pockets=None, pockets_sha256=None, **kwargs)

    def pocket_probability(self, padded: PaddedTer, state: ExplorationState,
                           frontiers: list[Frontier]) -> np.ndarray:
        out = np.zeros(len(padded.node_mask), np.float32)
        nodes, which = node_frontiers(padded, state.grid, frontiers)
        if len(nodes):
            area = pocket_areas(state.grid, self.building(state),
                                [frontiers[i] for i in which])
            out[nodes] = area < self.small_area_m2
        return out

    def building(self, state: ExplorationState) -> GridMap:
        """The map the pockets are read from: the ground truth."""
        assert state.ground_truth is not None  # Privileged: run with the ground truth.
        return state.ground_truth
