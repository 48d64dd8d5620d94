"""Frontiers and their information gain.

A frontier cell is an unknown cell with a free 4-neighbour (Yamauchi 1997). Frontier
cells are grouped into 8-connected clusters; clusters longer than ``max_length`` are cut
into pieces along their main axis, so that each frontier stands for one place to go.

Information gain comes in two flavours:

* :func:`information_gain` is the paper's definition and needs the ground truth: the
  unexplored free space (free in the ground truth, unknown in the map) is split into
  connected components with OpenCV's connected-components labelling; a component belongs
  to every frontier whose cells are 8-adjacent to (or part of) it; a frontier's gain is the
  summed area of its components over the ground truth's total free area. It is used for
  rewards and analysis, where the simulator knows the truth.
* :func:`estimated_information_gain` uses the partial map alone, as a deployed robot must:
  the share of unknown cells in the square window of side ``2 * radius`` around the
  frontier's centre (an integral image makes it O(1) per frontier). It is what the TER's
  node features carry by default.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from mjexplore.maps import GridMap

FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.uint8)
EIGHT_NEIGHBOURS = np.ones((3, 3), np.uint8)


@dataclasses.dataclass(frozen=True)
class Frontier:
    """One frontier.

    Attributes:
        cells: (k, 2) int (row, col) of its frontier cells.
        centre: (x, y) mean position of its cells in the ``map`` frame, metres.
        goal_cell: (row, col) of the free cell next to the frontier cell nearest the centre:
            the place a robot drives to.
        goal: (x, y) of ``goal_cell``'s centre, metres.
    """

    cells: np.ndarray
    centre: np.ndarray
    goal_cell: tuple[int, int]
    goal: np.ndarray

    @property
    def size(self) -> int:
        return len(self.cells)


def frontier_mask(grid: GridMap) -> np.ndarray:
    """Boolean mask of unknown cells with at least one free 4-neighbour."""
    free = grid.free.astype(np.uint8)
    near_free = cv2.dilate(free, FOUR_NEIGHBOURS, borderType=cv2.BORDER_CONSTANT,
                           borderValue=0).astype(bool)
    return (grid.data < 0) & near_free


def _split(cells: np.ndarray, max_cells: float) -> list[np.ndarray]:
    """Cuts a cluster into ceil(extent / max_cells) runs along its principal axis."""
    extent = np.ptp(cells, axis=0).max() + 1
    pieces = int(np.ceil(extent / max_cells))
    if pieces <= 1:
        return [cells]
    centred = cells - cells.mean(axis=0)
    _, _, vt = np.linalg.svd(centred.astype(float), full_matrices=False)
    order = np.argsort(centred @ vt[0], kind="stable")
    return [cells[idx] for idx in np.array_split(order, pieces)]


def find_frontiers(grid: GridMap, min_size: int = 3, max_length: float = 2.0) -> list[Frontier]:
    """Frontier clusters of a map, in a deterministic order (OpenCV's label order).

    Args:
        grid: The partial map.
        min_size: Clusters with fewer cells are noise and dropped.
        max_length: Clusters longer than this (metres) are cut into pieces.
    """
    mask = frontier_mask(grid)
    flat = np.flatnonzero(mask.reshape(-1))  # Much faster than 2D nonzero on bool.
    if len(flat) == 0:
        return []
    rows, cols = np.divmod(flat, mask.shape[1])
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    lab = labels[rows, cols]
    order = np.argsort(lab, kind="stable")
    cells_all = np.column_stack([rows, cols])[order]
    bounds = np.flatnonzero(np.diff(lab[order])) + 1
    free = grid.free
    out = []
    for group in np.split(cells_all, bounds):
        if len(group) < min_size:
            continue
        for cells in _split(group, max_length / grid.resolution):
            centre = grid.cell_to_world(cells.mean(axis=0))
            nearest = cells[np.argmin(((cells - cells.mean(axis=0)) ** 2).sum(axis=1))]
            goal_cell = _free_neighbour(free, nearest)
            out.append(Frontier(cells, centre, goal_cell, grid.cell_to_world(np.array(goal_cell))))
    return out


def _free_neighbour(free: np.ndarray, cell: np.ndarray) -> tuple[int, int]:
    r, c = int(cell[0]), int(cell[1])
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        rr, cc = r + dr, c + dc
        if 0 <= rr < free.shape[0] and 0 <= cc < free.shape[1] and free[rr, cc]:
            return rr, cc
    raise AssertionError("a frontier cell always has a free 4-neighbour")


def information_gain(grid: GridMap, ground_truth: GridMap,
                     frontiers: list[Frontier]) -> np.ndarray:
    """The paper's information gain of each frontier (needs the ground truth).

    Returns:
        float array, one value per frontier: area of the unexplored free-space components
        8-adjacent to the frontier, over the ground truth's free area.
    """
    if not frontiers:
        return np.zeros(0)
    unexplored = (ground_truth.free & (grid.data < 0)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(unexplored, connectivity=8)
    areas = stats[:, cv2.CC_STAT_AREA].astype(float)
    areas[0] = 0.0  # Label 0 is everything that is not unexplored free space.
    total_free = float(ground_truth.free.sum())
    rows, cols = labels.shape
    gains = np.zeros(len(frontiers))
    offsets = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    for i, f in enumerate(frontiers):
        near = (f.cells[:, None, :] + offsets[None]).reshape(-1, 2)
        near = near[(near[:, 0] >= 0) & (near[:, 0] < rows) & (near[:, 1] >= 0) &
                    (near[:, 1] < cols)]
        components = np.unique(labels[near[:, 0], near[:, 1]])
        gains[i] = areas[components].sum() / total_free
    return gains


def estimated_information_gain(grid: GridMap, frontiers: list[Frontier],
                               radius: float = 2.0) -> np.ndarray:
    """Share of unknown cells around each frontier's centre, from the partial map alone.

    Returns:
        float array in [0, 1], one value per frontier.
    """
    if not frontiers:
        return np.zeros(0)
    unknown = (grid.data < 0).astype(np.uint8)
    integral = cv2.integral(unknown, sdepth=cv2.CV_32S)  # (rows + 1, cols + 1)
    k = max(1, int(round(radius / grid.resolution)))
    rows, cols = unknown.shape
    centres = np.array([grid.world_to_cell(f.centre) for f in frontiers])
    r0 = np.clip(centres[:, 0] - k, 0, rows)
    r1 = np.clip(centres[:, 0] + k + 1, 0, rows)
    c0 = np.clip(centres[:, 1] - k, 0, cols)
    c1 = np.clip(centres[:, 1] + k + 1, 0, cols)
    counts = integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0]
    return counts / float((2 * k + 1) ** 2)
