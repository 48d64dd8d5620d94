"""Frontiers and their information gain.

A frontier cell is an unknown cell with a free 4-neighbour (Yamauchi 1997). Frontier
cells are grouped into 8-connected clusters; clusters longer than ``max_length`` are cut
into pieces along their longer axis, so that each frontier stands for one place to go.

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

from mjexplore.maps import GridMap, is_free, window_counts

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


def frontier_mask(grid: GridMap, free: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of unknown cells with at least one free 4-neighbour.

    ``free`` is ``grid.free`` if already computed.
    """
    free = (grid.free if free is None else free).astype(np.uint8)
    near_free = cv2.dilate(free, FOUR_NEIGHBOURS, borderType=cv2.BORDER_CONSTANT,
                           borderValue=0).astype(bool)
    return (grid.data < 0) & near_free


def _split(cells: np.ndarray, max_cells: float) -> list[np.ndarray]:
    """Cuts a cluster into ceil(extent / max_cells) runs along its longer grid axis."""
    extent = np.ptp(cells, axis=0)
    axis = int(np.argmax(extent))
    pieces = int(np.ceil((extent[axis] + 1) / max_cells))
    order = np.argsort(cells[:, axis], kind="stable")
    return [cells[idx] for idx in np.array_split(order, pieces)]


def find_frontiers(grid: GridMap, min_size: int = 3, max_length: float = 2.0,
                   free: np.ndarray | None = None,
                   within: tuple[slice, slice] | None = None) -> list[Frontier]:
    """Frontier clusters of a map, in a deterministic order (OpenCV's label order).

    Args:
        grid: The partial map.
        min_size: Clusters with fewer cells are noise and dropped.
        max_length: Clusters longer than this (metres) are cut into pieces.
        free: ``grid.free`` if already computed.
        within: (rows, cols) slices (steps of 1) of a part of the map outside which no cell
            is free, e.g. the bounding box of the cells ever known (what
            :class:`~mjexplore.topology.pipeline.TopologyTracker` keeps): only that part,
            grown by one cell, is read, and the frontiers are the same as without it.
    """
    if within is None:
        window = (slice(0, grid.shape[0]), slice(0, grid.shape[1]))
    else:  # Frontier cells lie next to free ones: one cell round the window.
        window = tuple(slice(max(s.start - 1, 0), min(s.stop + 1, n))
                       for s, n in zip(within, grid.shape))
    data = grid.data[window]
    free = is_free(data) if free is None else free[window]
    offset = np.array([window[0].start, window[1].start])
    # Frontier cells neighbour free ones: only the box round the free cells can hold them,
    # and labelling the box gives the whole map's labels in the same (raster) order.
    box = _free_box(free)
    if box is None:
        return []
    near_free = cv2.dilate(free[box].astype(np.uint8), FOUR_NEIGHBOURS,
                           borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    mask = (data[box] < 0) & near_free
    flat = np.flatnonzero(mask.reshape(-1))  # Much faster than 2D nonzero on bool.
    if len(flat) == 0:
        return []
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    lab = labels.reshape(-1)[flat]
    order = np.argsort(lab, kind="stable")
    lab = lab[order]
    cells = np.column_stack(np.divmod(flat[order], mask.shape[1])) + (
        box[0].start + offset[0], box[1].start + offset[1])
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    sizes = np.diff(np.r_[starts, len(lab)])
    extent = np.maximum(np.maximum.reduceat(cells, starts) - np.minimum.reduceat(cells, starts),
                        0).max(axis=1) + 1
    max_cells = max_length / grid.resolution
    groups: list[np.ndarray] = []
    for start, size, ext in zip(starts, sizes, extent):
        if size < min_size:
            continue
        group = cells[start:start + size]
        groups.extend(_split(group, max_cells) if ext > max_cells else [group])
    if not groups:
        return []
    # Per-group centre, the cell nearest to it, and that cell's free 4-neighbour: at once.
    gid = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
    allc = np.concatenate(groups)
    counts = np.bincount(gid).astype(float)
    means = np.column_stack([np.bincount(gid, allc[:, 0]), np.bincount(gid, allc[:, 1])])
    means /= counts[:, None]
    d2 = ((allc - means[gid]) ** 2).sum(axis=1)
    first = np.lexsort((d2, gid))
    nearest = allc[first[np.r_[0, np.flatnonzero(np.diff(gid[first])) + 1]]]
    # Every free cell is in the window, so its edge hides none of them.
    goal_cells = _free_neighbours(free, nearest - offset) + offset
    centres = grid.cell_to_world(means)
    goals = grid.cell_to_world(goal_cells)
    return [Frontier(group, centres[i], (int(goal_cells[i, 0]), int(goal_cells[i, 1])),
                     goals[i]) for i, group in enumerate(groups)]


def _free_box(free: np.ndarray) -> tuple[slice, slice] | None:
    """The rows and columns of the free cells' bounding box grown by one cell (clipped to
    the map), or None without free cells."""
    rows = np.flatnonzero(free.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(free.any(axis=0))
    return (slice(max(rows[0] - 1, 0), min(rows[-1] + 2, free.shape[0])),
            slice(max(cols[0] - 1, 0), min(cols[-1] + 2, free.shape[1])))


def _free_neighbours(free: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """For each (row, col), its first free 4-neighbour (east, north, west, south)."""
    rows, cols = free.shape
    steps = np.array([(0, 1), (1, 0), (0, -1), (-1, 0)])
    cand = cells[:, None, :] + steps[None]
    inside = (cand[..., 0] >= 0) & (cand[..., 0] < rows) & (cand[..., 1] >= 0) & (
        cand[..., 1] < cols)
    ok = np.zeros(inside.shape, bool)
    ok[inside] = free[cand[inside][:, 0], cand[inside][:, 1]]
    assert ok.any(axis=1).all(), "a frontier cell always has a free 4-neighbour"
    return cand[np.arange(len(cells)), ok.argmax(axis=1)]


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
    k = max(1, int(round(radius / grid.resolution)))
    centres = grid.world_to_cell(np.array([f.centre for f in frontiers]))
    counts = window_counts(grid.data < 0, centres, k)
    return counts / float((2 * k + 1) ** 2)
