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
import numba
import numpy as np

from mjexplore.maps import GridMap, is_free, window_counts

FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.uint8)
EIGHT_NEIGHBOURS = np.ones((3, 3), np.uint8)
# A cell and its 4-neighbours (row, col steps).
_DR4 = np.array([0, 0, 1, 0, -1], np.int64)
_DC4 = np.array([0, 1, 0, -1, 0], np.int64)


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


def find_frontiers(grid: GridMap, min_size: int = 3, max_length: float = 2.0,
                   free: np.ndarray | None = None) -> list[Frontier]:
    """Frontier clusters of a map, in a deterministic order (OpenCV's label order).

    :class:`FrontierMask` finds the same, kept current as the map changes.

    Args:
        grid: The partial map.
        min_size: Clusters with fewer cells are noise and dropped.
        max_length: Clusters longer than this (metres) are cut into pieces.
        free: ``grid.free`` if already computed.
    """
    free = grid.free if free is None else free
    # Frontier cells neighbour free ones: only the box round the free cells can hold them,
    # and labelling the box gives the whole map's labels in the same (raster) order.
    box = _free_box(free)
    if box is None:
        return []
    near_free = cv2.dilate(free[box].astype(np.uint8), FOUR_NEIGHBOURS,
                           borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    mask = (grid.data[box] < 0) & near_free
    flat = np.flatnonzero(mask.reshape(-1))  # Much faster than 2D nonzero on bool.
    if len(flat) == 0:
        return []
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    cells = np.column_stack(np.divmod(flat, mask.shape[1])) + (box[0].start, box[1].start)
    return _clusters(grid, cells, labels.reshape(-1)[flat], min_size, max_length)


def _clusters(grid: GridMap, cells: np.ndarray, lab: np.ndarray, min_size: int,
              max_length: float) -> list[Frontier]:
    """The frontiers of frontier cells ``cells`` ((k, 2) (row, col) in raster order) and
    their cluster labels ``lab`` (numbered in order of each cluster's first cell)."""
    order = np.argsort(lab, kind="stable")
    lab = lab[order]
    cells = cells[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    sizes = np.diff(np.r_[starts, len(lab)])
    ptp = np.maximum.reduceat(cells, starts) - np.minimum.reduceat(cells, starts)
    max_cells = max_length / grid.resolution
    # Clusters too long are cut into ceil(extent / max_cells) runs along their longer grid
    # axis, all at once: each one's cells sorted (stably) along it and dealt into pieces as
    # np.array_split deals them.
    axis = np.argmax(ptp, axis=1)
    too_long = ptp.max(axis=1) + 1 > max_cells
    pieces = np.where(too_long, np.ceil((ptp[np.arange(len(ptp)), axis] + 1) / max_cells),
                      1).astype(np.int64)
    cluster = np.repeat(np.arange(len(starts)), sizes)
    key = np.where(too_long[cluster], cells[np.arange(len(cells)), axis[cluster]], 0)
    order = np.lexsort((key, cluster))
    cells, cluster = cells[order], cluster[order]
    at = np.arange(len(cells)) - starts[cluster]
    size, count = sizes[cluster], pieces[cluster]
    small, extra = np.maximum(size // count, 1), size % count
    split = extra * (small + 1)
    piece = np.where(at < split, at // (small + 1), extra + (at - split) // small)
    kept = (sizes >= min_size)[cluster]
    cells, cluster, piece = cells[kept], cluster[kept], piece[kept]
    if len(cells) == 0:
        return []
    gid = np.cumsum(np.r_[False, (cluster[1:] != cluster[:-1]) | (piece[1:] != piece[:-1])])
    allc = cells
    groups = np.split(allc, np.flatnonzero(np.diff(gid)) + 1)
    # Per-group centre, the cell nearest to it, and that cell's free 4-neighbour: at once.
    counts = np.bincount(gid).astype(float)
    sums = np.column_stack([np.bincount(gid, allc[:, 0]), np.bincount(gid, allc[:, 1])])
    means = sums / counts[:, None]
    d2 = ((allc - means[gid]) ** 2).sum(axis=1)
    first = np.lexsort((d2, gid))
    nearest = allc[first[np.r_[0, np.flatnonzero(np.diff(gid[first])) + 1]]]
    goal_cells = _free_neighbours(grid.data, nearest)
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


def _free_neighbours(data: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """For each (row, col), its first 4-neighbour (east, north, west, south) known free in
    the map's cell values ``data``."""
    rows, cols = data.shape
    steps = np.array([(0, 1), (1, 0), (0, -1), (-1, 0)])
    cand = cells[:, None, :] + steps[None]
    inside = (cand[..., 0] >= 0) & (cand[..., 0] < rows) & (cand[..., 1] >= 0) & (
        cand[..., 1] < cols)
    ok = np.zeros(inside.shape, bool)
    ok[inside] = is_free(data[cand[inside][:, 0], cand[inside][:, 1]])
    assert ok.any(axis=1).all(), "a frontier cell always has a free 4-neighbour"
    return cand[np.arange(len(cells)), ok.argmax(axis=1)]


@numba.njit(cache=True)
def _refresh_mask(data, cols, cells, mask, where, listed, n_listed, box):
    """Sets ``mask`` (flat, 1 on frontier cells) anew at each flat cell of ``cells`` and its
    4-neighbours, from the flat cell values ``data``; the frontier cells stay listed in
    ``listed[:n_listed]`` (any order; ``where`` holds each one's place), which needs room
    for 5 more per cell. ``box`` (first row, last row, first col, last col) grows to hold
    ``cells``. Returns the new ``n_listed``."""
    rows = len(data) // cols
    for c in cells:
        r0, c0 = c // cols, c % cols
        box[0], box[1] = min(box[0], r0), max(box[1], r0)
        box[2], box[3] = min(box[2], c0), max(box[3], c0)
        for k in range(5):
            rr, cc = r0 + _DR4[k], c0 + _DC4[k]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            y = rr * cols + cc
            flag = 0
            if data[y] < 0:
                for j in range(1, 5):
                    nr, nc = rr + _DR4[j], cc + _DC4[j]
                    if 0 <= nr < rows and 0 <= nc < cols and 0 <= data[nr * cols + nc] < 50:
                        flag = 1
                        break
            if flag and not mask[y]:
                where[y] = n_listed
                listed[n_listed] = y
                n_listed += 1
            elif mask[y] and not flag:  # The last listed cell takes y's place.
                n_listed -= 1
                last = listed[n_listed]
                listed[where[y]] = last
                where[last] = where[y]
            mask[y] = flag
    return n_listed


@numba.njit(cache=True)
def _first_free(data, r0, r1, c0, c1):
    """(first row, first column) holding a cell known free in ``data[r0:r1, c0:c1]`` (rows,
    columns of the whole map), or (-1, -1) when none is free."""
    first_row = -1
    for r in range(r0, r1):
        for c in range(c0, c1):
            if 0 <= data[r, c] < 50:
                first_row = r
                break
        if first_row >= 0:
            break
    if first_row < 0:
        return -1, -1
    for c in range(c0, c1):
        for r in range(first_row, r1):
            if 0 <= data[r, c] < 50:
                return first_row, c
    return -1, -1  # Unreachable: the first row holds a free cell.


@numba.njit(cache=True)
def _block_labels(flat, cols, r0, c0):
    """8-connected cluster labels of the sorted flat cells ``flat``, numbered as OpenCV's
    ``connectedComponents`` numbers them (from 0) on an image whose corner is cell (r0, c0):
    in the raster order of the 2 x 2 blocks of the image where each cluster first appears
    (the cells of one block are all 8-adjacent, so no two clusters share a first block)."""
    n = len(flat)
    parent = np.arange(n)
    for i in range(n):
        c = flat[i]
        r, col = c // cols, c % cols
        # The neighbours met before c in a raster scan: west, then the row below.
        for k in range(4):
            dr, dc = (0, -1, -1, -1)[k], (-1, -1, 0, 1)[k]
            if col + dc < 0 or col + dc >= cols or r + dr < 0:
                continue
            y = c + dr * cols + dc
            j = np.searchsorted(flat[:i], y)
            if j < i and flat[j] == y:
                a, b = i, j
                while parent[a] != a:
                    a = parent[a]
                while parent[b] != b:
                    b = parent[b]
                if a != b:
                    parent[max(a, b)] = min(a, b)
    first_block = np.full(n, np.int64(1) << 62)
    for i in range(n):
        a = i
        while parent[a] != a:
            a = parent[a]
        parent[i] = a
        r, col = flat[i] // cols, flat[i] % cols
        block = ((r - r0) // 2) * cols + (col - c0) // 2
        if block < first_block[a]:
            first_block[a] = block
    roots = np.flatnonzero(parent == np.arange(n))
    number = np.empty(n, np.int64)
    number[roots[np.argsort(first_block[roots])]] = np.arange(len(roots))
    labels = np.empty(n, np.int64)
    for i in range(n):
        labels[i] = number[parent[i]]
    return labels


class FrontierMask:
    """The frontier cells of a map kept current cell by cell (as :func:`frontier_mask`),
    and listed, so that reading them costs nothing per map cell; told every change of the
    map after :meth:`reset`.

    Args:
        shape: (rows, cols) of the map.

    Attributes:
        box: int64 (first row, last row, first col, last col) of the cells known at the
            reset or changed since: no free cell lies outside (first > last: none).
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        n = self.shape[0] * self.shape[1]
        self._mask = np.zeros(n, np.uint8)
        self._where = np.zeros(n, np.int32)  # Places in _listed (< n cells).
        self._listed = np.empty(1024, np.int64)
        self._n = 0
        self.box = np.array([n, -1, n, -1], np.int64)

    @property
    def mask(self) -> np.ndarray:
        """(rows, cols) uint8, 1 on frontier cells (a view)."""
        return self._mask.reshape(self.shape)

    def reset(self, grid: GridMap) -> None:
        """Finds the frontier cells and the known cells' box of the whole map."""
        self._mask[:] = 0
        self._n = 0
        self.update(grid, np.flatnonzero(frontier_mask(grid)))
        known = grid.known
        rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
        n = self._mask.size
        self.box[:] = (rows[0], rows[-1], cols[0], cols[-1]) if len(rows) else (n, -1, n, -1)

    def update(self, grid: GridMap, cells: np.ndarray) -> None:
        """Refreshes the cells around ``cells`` (flat indices whose value changed)."""
        cells = np.asarray(cells, np.int64)
        need = self._n + 5 * len(cells)
        if need > len(self._listed):
            grown = np.empty(max(need, 2 * len(self._listed)), np.int64)
            grown[:self._n] = self._listed[:self._n]
            self._listed = grown
        self._n = _refresh_mask(grid.data.reshape(-1), self.shape[1], cells, self._mask,
                                self._where, self._listed, self._n, self.box)

    def frontiers(self, grid: GridMap, min_size: int = 3,
                  max_length: float = 2.0) -> list[Frontier]:
        """:func:`find_frontiers` of ``grid`` (the map the mask follows), with the same
        arguments; the map is read in ``box`` alone."""
        r0, r1, c0, c1 = (int(v) for v in self.box)
        # find_frontiers labels the free cells' box grown by one cell: its corner sets
        # OpenCV's 2 x 2 blocks, hence the clusters' order.
        first_row, first_col = _first_free(grid.data, r0, r1 + 1, c0, c1 + 1)
        if first_row < 0 or self._n == 0:
            return []
        flat = np.sort(self._listed[:self._n])
        labels = _block_labels(flat, self.shape[1], max(first_row - 1, 0),
                               max(first_col - 1, 0))
        return _clusters(grid, np.column_stack(np.divmod(flat, self.shape[1])), labels,
                         min_size, max_length)


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
