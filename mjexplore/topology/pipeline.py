"""Keeping the topology of a growing map up to date: GVD, graph, frontiers and TER.

:class:`TopologyTracker` is fed the cells the mapper reports as changed after each scan
(cheap: the GVD is updated incrementally) and builds the TER when a decision is due.

Unknown space. The GVD's obstacles are the *occupied* cells only, and its distance field
covers the known cells only (obstacles spread through known space; unknown space is
neither obstacle nor part of the field), so the diagram is the GVD of the known free space
between known walls. Treating unknown cells as obstacles instead would bend the diagram
around the ragged arc where each scan's reach ends (a comb of false lines between
neighbouring arc cells) and would raise the field around every cell a scan clears; here
the diagram's lines run on to the edge of the explored region, where frontier nodes join
them. This is the GVD "of the historic scanned area" the paper builds its TER on.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mjexplore.maps import GridMap, is_known, is_occupied
from mjexplore.topology.frontiers import (
    Frontier,
    FrontierMask,
    estimated_information_gain,
    find_frontiers,
    information_gain,
)
from mjexplore.topology.graph import GraphConfig, GvdGraph, build_graph
from mjexplore.topology.gvd import DynamicGVD
from mjexplore.topology.ter import Ter, TerConfig, build_ter


@dataclasses.dataclass(frozen=True, kw_only=True)
class TopologyConfig:
    """Settings of the topology layer.

    Attributes:
        graph: GVD graph extraction (max side length, pruning).
        ter: TER assembly and padding.
        frontier_min_size: Frontier clusters with fewer cells are ignored.
        frontier_max_length: Longer frontiers are split, metres.
        gain: 'estimated' (from the partial map, deployable) or 'ground_truth' (the
            paper's definition; needs the ground truth) for the TER's G_info.
        gain_radius: Window half-side of the estimated gain, metres.
    """

    graph: GraphConfig = dataclasses.field(default_factory=GraphConfig)
    ter: TerConfig = dataclasses.field(default_factory=TerConfig)
    frontier_min_size: int = 3
    frontier_max_length: float = 2.0
    gain: str = "estimated"
    gain_radius: float = 2.0

    def __post_init__(self) -> None:
        if self.gain not in ("estimated", "ground_truth"):
            raise ValueError(f"gain must be 'estimated' or 'ground_truth', not {self.gain!r}")


class TopologyTracker:
    """The GVD of a map kept current, and TERs built from it on demand.

    Args:
        shape: (rows, cols) of the map.
        config: Topology settings.
        ground_truth: Needed when ``config.gain == 'ground_truth'``.
    """

    def __init__(self, shape: tuple[int, int], config: TopologyConfig | None = None,
                 ground_truth: GridMap | None = None) -> None:
        self.config = config or TopologyConfig()
        if self.config.gain == "ground_truth" and ground_truth is None:
            raise ValueError("ground-truth information gain needs the ground truth map")
        self.ground_truth = ground_truth
        self.gvd = DynamicGVD(shape)
        # (map cell array, its frontiers) as last observed.
        self._frontiers: tuple[np.ndarray, list[Frontier]] | None = None
        self._frontier_mask = FrontierMask(shape)
        self._frontier_data: np.ndarray | None = None  # The cell array the mask follows.

    def observe(self, grid: GridMap, changed: np.ndarray | None = None) -> int:
        """Updates the GVD after the map changed.

        Args:
            grid: The map (its occupied cells are the GVD's obstacles).
            changed: (k, 2) (row, col) cells that changed, as the mapper reports them;
                None compares the whole map.

        Returns:
            Number of cells whose distance field changed.
        """
        self._frontiers = None
        if changed is None:
            self._frontier_mask.reset(grid)
            self._frontier_data = grid.data
            return self.gvd.update(grid.occupied, grid.known)
        cells = changed[:, 0].astype(np.int64) * grid.shape[1] + changed[:, 1]
        if self._frontier_data is grid.data:
            self._frontier_mask.update(grid, cells)
        else:  # A map not seen before: its frontiers are found once, then kept.
            self._frontier_mask.reset(grid)
            self._frontier_data = grid.data
        values = grid.data.reshape(-1)[cells]
        return self.gvd.update_cells(cells, is_occupied(values), is_known(values))

    def frontiers(self, grid: GridMap, free: np.ndarray | None = None) -> list[Frontier]:
        """The map's frontiers (:func:`find_frontiers` with the configured sizes).

        Found once per map state: kept until the next :meth:`observe` (or a call with
        another map), so the explorer's view and the TER of one decision share them. On
        the map observed last they come from the frontier cells kept current scan by scan,
        read in the box of the known cells (no free cell lies outside it): the cost grows
        with the explored part and the frontiers, not with the map.

        Args:
            grid: The map.
            free: ``grid.free`` if already computed; read only for a map other than the
                one observed last (the kept frontier cells need no free mask).
        """
        if self._frontiers is None or self._frontiers[0] is not grid.data:
            cfg = self.config
            if self._frontier_data is grid.data:
                found = self._frontier_mask.frontiers(grid, cfg.frontier_min_size,
                                                      cfg.frontier_max_length)
            else:
                found = find_frontiers(grid, cfg.frontier_min_size, cfg.frontier_max_length,
                                       free)
            self._frontiers = grid.data, found
        return self._frontiers[1]

    def graph(self, grid: GridMap, free: np.ndarray | None = None) -> GvdGraph:
        """The GVD graph; ``free`` is ``grid.free`` if already computed."""
        free = grid.free if free is None else free
        return build_graph(self.gvd.voronoi & free, self.gvd.distance2, free, grid.resolution,
                           self.config.graph)

    def ter(self, grid: GridMap, robot_pose: np.ndarray,
            config: TopologyConfig | None = None) -> tuple[Ter, list, np.ndarray]:
        """Builds the TER for a decision.

        Args:
            grid: The map.
            robot_pose: (x, y, yaw) in the ``map`` frame.
            config: Settings of the TER's information gain and assembly (``gain``,
                ``gain_radius``, ``ter``) when they differ from the tracker's, e.g. those a
                policy was trained with; frontiers and the GVD stay the tracker's.

        Returns:
            (ter, frontiers, gains): the TER, the frontiers found and their information
            gain (as configured).
        """
        cfg = config or self.config
        if cfg.gain == "ground_truth" and self.ground_truth is None:
            raise ValueError("ground-truth information gain needs the ground truth map")
        free = grid.free
        frontiers = self.frontiers(grid, free)
        if cfg.gain == "ground_truth":
            assert self.ground_truth is not None  # Checked above.
            gains = information_gain(grid, self.ground_truth, frontiers)
        else:
            gains = estimated_information_gain(grid, frontiers, cfg.gain_radius)
        ter = build_ter(self.graph(grid, free), grid, frontiers, gains, robot_pose, cfg.ter,
                        free)
        return ter, frontiers, gains
