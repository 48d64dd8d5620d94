"""An incrementally updated distance map and Generalized Voronoi Diagram (GVD).

A dynamic brushfire in the manner of Lau, Sprunk and Burgard (IROS 2010, "Improved updating
of Euclidean distance maps and Voronoi diagrams"): every cell stores its nearest obstacle
cell and the squared distance to it; when obstacles appear, a *lower* wave spreads the new
obstacle outward, and when they disappear, a *raise* wave clears the cells that referred to
them, after which the surrounding cells lower into the gap. Only cells whose nearest
obstacle can change are touched, so an update costs time in proportion to the change.

What counts as an obstacle: occupied *and unknown* cells. The GVD is thus the GVD of the
known free space: it runs midway between walls, and between walls and the boundary of the
unexplored region, ending where the map does (this is how the paper grows its GVD "from
the historic scanned area"). Frontier nodes are joined to it in :mod:`mjexplore.topology.ter`.

Domain. The field can be limited to a set of cells (the known part of a map): obstacles
spread only through chains of domain cells, and cells outside keep no value. Cells enter
(their neighbours spread into them) and leave (raised, with whatever depended on them)
incrementally like obstacles do.

Determinism. Two rules make the stored field a function of the obstacle set and domain
alone, so that an incremental update gives exactly what a recomputation from scratch
gives:

* ties between obstacles at equal distance go to the lower cell index;
* a cell takes an obstacle only from a neighbour strictly closer to that obstacle, and a
  cell that loses that support is raised and recomputed.

Voronoi cells are then a local function of the field (Lau's ``checkVoro`` test, applied to
every neighbour pair): cell ``c`` is on the GVD if a neighbour ``n`` has a different,
non-adjacent nearest obstacle, ``c`` is no less stable than ``n``, ``c`` is more than
sqrt(2) cells from its obstacle. The GVD so defined is connected wherever the free space
is; its spurs into concave corners and off the ends of thick walls are pruned later, as
leaf branches that end near an obstacle (:mod:`mjexplore.topology.graph`).
"""

from __future__ import annotations

import numba
import numpy as np

from mjexplore.heap import grow as _heap_grow
from mjexplore.heap import pop as _heap_pop
from mjexplore.heap import push as _heap_push

INF = np.int64(1) << np.int64(40)
_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1], np.int64)
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1], np.int64)
# Heap entries one step of :func:`_update` can push: 8 neighbours, each pushed and clearing
# up to 8 of its own (:func:`_drop_unsupported`).
_ROOM = 72

# The helpers below are inlined into the kernels (numba ``inline="always"``): as calls they
# cost reference-count updates on every array argument, more than the work they do. Cell
# rows and columns are computed once per cell (integer division is slow) and distances from
# them.


@numba.njit(cache=True, inline="always")
def _supported(y, cols, rows, obst, to_raise):
    """True if a neighbour of ``y`` holds y's obstacle and is strictly closer to it."""
    o = obst[y]
    r, c = y // cols, y % cols
    orow, ocol = o // cols, o % cols
    dy = (r - orow) * (r - orow) + (c - ocol) * (c - ocol)
    for k in range(8):
        rr, cc = r + _DR[k], c + _DC[k]
        if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
            continue
        z = rr * cols + cc
        if obst[z] == o and not to_raise[z] and (
                (rr - orow) * (rr - orow) + (cc - ocol) * (cc - ocol) < dy):
            return True
    return False


@numba.njit(cache=True, inline="always")
def _mark(c, stamp, stamp_id, changed, n_changed):
    """Lists cell ``c`` as changed (once per update)."""
    if stamp[c] != stamp_id:
        stamp[c] = stamp_id
        changed[n_changed] = c
        n_changed += 1
    return n_changed


@numba.njit(cache=True, inline="always")
def _clear(c, lost, n, obst, dist2, to_raise, raise_obst, stamp, stamp_id, changed,
           n_changed, keys, vals, size):
    """Forgets cell c's value (it referred to ``lost``) and queues it to raise; returns
    (heap size, n_changed)."""
    raise_obst[c] = lost
    size = _heap_push(keys, vals, size, dist2[c] * n + c, c)
    obst[c] = -1
    dist2[c] = INF
    to_raise[c] = 1
    return size, _mark(c, stamp, stamp_id, changed, n_changed)


@numba.njit(cache=True, inline="always")
def _drop_unsupported(x, lost, rows, cols, occ, obst, dist2, to_raise, raise_obst, stamp,
                      stamp_id, changed, n_changed, keys, vals, size):
    """Clears the neighbours of x that held ``lost`` and have no closer support left;
    returns (heap size, n_changed)."""
    n = rows * cols
    xr, xc = x // cols, x % cols
    for k in range(8):
        rr, cc = xr + _DR[k], xc + _DC[k]
        if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
            continue
        y = rr * cols + cc
        if obst[y] == lost and not occ[y] and not to_raise[y] and not _supported(
                y, cols, rows, obst, to_raise):
            size, n_changed = _clear(y, lost, n, obst, dist2, to_raise, raise_obst, stamp,
                                     stamp_id, changed, n_changed, keys, vals, size)
    return size, n_changed


@numba.njit(cache=True)
def _update(rows, cols, occ, domain, obst, dist2, raise_obst, to_raise, stamp, stamp_id,
            changed, set_cells, clear_cells, enter_cells, leave_cells, keys, vals):
    """Applies obstacle and domain changes and runs the raise/lower waves to completion.

    Returns (keys, vals, n_changed): the (possibly grown) heap arrays and the number of
    cells whose field changed, listed in ``changed``.
    """
    n = rows * cols
    size = 0
    n_changed = 0
    # Room for what the changes push before the waves run (see _ROOM).
    room = 9 * len(set_cells) + len(leave_cells) + 8 * len(enter_cells) + len(clear_cells)
    if room > len(keys):
        keys, vals = _heap_grow(keys, vals, size, room)
    for c in set_cells:
        if occ[c]:
            continue
        occ[c] = 1
        domain[c] = 1
        old = obst[c]
        obst[c] = c
        dist2[c] = 0
        to_raise[c] = 0
        n_changed = _mark(c, stamp, stamp_id, changed, n_changed)
        size = _heap_push(keys, vals, size, c, c)
        if old >= 0 and old != c:
            size, n_changed = _drop_unsupported(
                c, old, rows, cols, occ, obst, dist2, to_raise, raise_obst, stamp, stamp_id,
                changed, n_changed, keys, vals, size)
    for c in leave_cells:
        domain[c] = 0
        if obst[c] >= 0 and not occ[c]:
            size, n_changed = _clear(c, obst[c], n, obst, dist2, to_raise, raise_obst,
                                     stamp, stamp_id, changed, n_changed, keys, vals, size)
    for c in enter_cells:
        domain[c] = 1
        r0, c0 = c // cols, c % cols
        for k in range(8):  # Neighbours with a value spread it into the new cell.
            rr, cc = r0 + _DR[k], c0 + _DC[k]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            y = rr * cols + cc
            if domain[y] and obst[y] >= 0 and not to_raise[y]:
                size = _heap_push(keys, vals, size, dist2[y] * n + y, y)
    for c in clear_cells:
        if not occ[c]:
            continue
        occ[c] = 0
        size, n_changed = _clear(c, c, n, obst, dist2, to_raise, raise_obst, stamp, stamp_id,
                                 changed, n_changed, keys, vals, size)
    while size > 0:
        key, s, size = _heap_pop(keys, vals, size)
        if size + _ROOM > len(keys):
            keys, vals = _heap_grow(keys, vals, size, _ROOM)
        r0, c0 = s // cols, s % cols
        if to_raise[s]:
            lost = raise_obst[s]
            for k in range(8):
                rr, cc = r0 + _DR[k], c0 + _DC[k]
                if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                    continue
                y = rr * cols + cc
                if to_raise[y] or obst[y] < 0 or not domain[y]:
                    continue
                o = obst[y]
                if (not occ[o]) or (o == lost and not occ[y] and not _supported(
                        y, cols, rows, obst, to_raise)):
                    size, n_changed = _clear(y, o, n, obst, dist2, to_raise, raise_obst,
                                             stamp, stamp_id, changed, n_changed, keys, vals,
                                             size)
                else:  # A valid neighbour: let it spread into the cleared cell.
                    size = _heap_push(keys, vals, size, dist2[y] * n + y, y)
            to_raise[s] = 0
            continue
        o = obst[s]
        if o < 0 or key != dist2[s] * n + s:
            continue  # Cleared, or a newer entry for this cell is queued.
        ds = dist2[s]
        orow, ocol = o // cols, o % cols
        for k in range(8):
            rr, cc = r0 + _DR[k], c0 + _DC[k]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            y = rr * cols + cc
            if to_raise[y] or occ[y] or not domain[y]:
                continue
            d = (rr - orow) * (rr - orow) + (cc - ocol) * (cc - ocol)
            if d <= ds:
                continue  # Obstacles spread outward only.
            old = obst[y]
            if old < 0 or d < dist2[y] or (d == dist2[y] and o < old):
                obst[y] = o
                dist2[y] = d
                n_changed = _mark(y, stamp, stamp_id, changed, n_changed)
                size = _heap_push(keys, vals, size, d * n + y, y)
                if old >= 0 and old != o:
                    size, n_changed = _drop_unsupported(
                        y, old, rows, cols, occ, obst, dist2, to_raise, raise_obst, stamp,
                        stamp_id, changed, n_changed, keys, vals, size)
    return keys, vals, n_changed


@numba.njit(cache=True, inline="always")
def _is_voro(c, rows, cols, occ, obst, dist2):
    if occ[c] or obst[c] < 0 or dist2[c] <= 2:
        return False
    oc = obst[c]
    r0, c0 = c // cols, c % cols
    ocr, occ_ = oc // cols, oc % cols
    for k in (1, 3, 4, 6):  # Edge neighbours: the pair straddles the bisector within 1 cell.
        rr, cc = r0 + _DR[k], c0 + _DC[k]
        if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
            continue
        nb = rr * cols + cc
        on = obst[nb]
        if on < 0 or on == oc:
            continue
        onr, onc = on // cols, on % cols
        if abs(onr - ocr) <= 1 and abs(onc - occ_) <= 1:
            continue  # Neighbouring obstacle cells are one obstacle.
        stab_c = (r0 - onr) * (r0 - onr) + (c0 - onc) * (c0 - onc) - dist2[c]
        stab_n = (rr - ocr) * (rr - ocr) + (cc - occ_) * (cc - occ_) - dist2[nb]
        if 0 <= stab_c <= stab_n:
            return True
    return False


@numba.njit(cache=True)
def _refresh_voro(cells, rows, cols, occ, obst, dist2, voro, seen, seen_id):
    """Recomputes the GVD flag of ``cells`` and their neighbours, each once: ``seen`` is
    set to ``seen_id`` on the cells done."""
    for c in cells:
        r0, c0 = c // cols, c % cols
        for k in range(-1, 8):
            if k < 0:
                y = c
            else:
                rr, cc = r0 + _DR[k], c0 + _DC[k]
                if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                    continue
                y = rr * cols + cc
            if seen[y] != seen_id:
                seen[y] = seen_id
                voro[y] = _is_voro(y, rows, cols, occ, obst, dist2)


class DynamicGVD:
    """Distance map and GVD over a grid, updated as cells become obstacles or free.

    Args:
        shape: (rows, cols).

    Attributes:
        occupied: uint8 (rows, cols) obstacle flags (a view of the internal state).
        distance2: int64 (rows, cols) squared distance to the nearest obstacle, in cells^2
            (``INF`` where there is none).
        nearest: int64 (rows, cols) flat index of the nearest obstacle (-1 for none).
        voronoi: bool (rows, cols) GVD cells.
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        n = self.shape[0] * self.shape[1]
        self._occ = np.zeros(n, np.uint8)
        self._domain = np.zeros(n, np.uint8)
        self._obst = np.full(n, -1, np.int64)
        self._dist2 = np.full(n, INF, np.int64)
        self._raise_obst = np.full(n, -1, np.int64)
        self._to_raise = np.zeros(n, np.uint8)
        self._stamp = np.zeros(n, np.int64)
        self._stamp_id = 0
        self._changed = np.empty(n, np.int64)
        self._voro = np.zeros(n, np.bool_)
        self._voro_stamp = np.zeros(n, np.int64)  # Cells whose flag an update refreshed.
        self.last_changed = self._changed[:0]  # Flat cells the last update changed.
        self._keys = np.empty(1024, np.int64)
        self._vals = np.empty(1024, np.int64)

    @property
    def occupied(self) -> np.ndarray:
        return self._occ.reshape(self.shape)

    @property
    def distance2(self) -> np.ndarray:
        return self._dist2.reshape(self.shape)

    @property
    def nearest(self) -> np.ndarray:
        return self._obst.reshape(self.shape)

    @property
    def voronoi(self) -> np.ndarray:
        return self._voro.reshape(self.shape)

    def update(self, obstacles: np.ndarray, domain: np.ndarray | None = None,
               cells: np.ndarray | None = None) -> int:
        """Brings the field in line with ``obstacles`` within ``domain``.

        Args:
            obstacles: (rows, cols) bool, True where the cell is an obstacle.
            domain: (rows, cols) bool, the cells the field covers (obstacles always do);
                obstacles reach a cell only through chains of domain cells. None: all.
            cells: flat indices of the only cells that may have changed (e.g. from the
                mapper); None compares the whole grid.

        Returns:
            Number of cells whose distance or nearest obstacle changed.
        """
        obst_flat = np.ascontiguousarray(obstacles).reshape(-1)
        dom_flat = (np.ones_like(obst_flat) if domain is None else
                    np.ascontiguousarray(domain).reshape(-1))
        if cells is None:
            cells = np.flatnonzero((obst_flat != self._occ.astype(bool)) |
                                   ((dom_flat | obst_flat) != self._domain.astype(bool)))
        cells = np.asarray(cells, np.int64)
        return self.update_cells(cells, obst_flat[cells], dom_flat[cells])

    def update_cells(self, cells: np.ndarray, obstacle: np.ndarray, domain: np.ndarray) -> int:
        """:meth:`update` given only the cells that may have changed and their new state.

        Costs nothing per map cell, only per cell given.

        Args:
            cells: Flat indices (int64) of the cells.
            obstacle: Bool per cell, True if it is now an obstacle.
            domain: Bool per cell, True if the field now covers it (obstacles always do).

        Returns:
            Number of cells whose distance or nearest obstacle changed.
        """
        want_obst = obstacle
        want_dom = domain | obstacle
        occ = self._occ[cells] == 1
        dom = self._domain[cells] == 1
        to_set = cells[want_obst & ~occ]
        to_clear = cells[~want_obst & occ]
        enter = cells[want_dom & ~dom & ~want_obst]
        leave = cells[~want_dom & dom]
        if not (len(to_set) or len(to_clear) or len(enter) or len(leave)):
            self.last_changed = self._changed[:0]
            return 0
        self._stamp_id += 1
        self._keys, self._vals, n_changed = _update(
            self.shape[0], self.shape[1], self._occ, self._domain, self._obst, self._dist2,
            self._raise_obst, self._to_raise, self._stamp, self._stamp_id, self._changed,
            to_set, to_clear, enter, leave, self._keys, self._vals)
        _refresh_voro(self._changed[:n_changed], self.shape[0], self.shape[1], self._occ,
                      self._obst, self._dist2, self._voro, self._voro_stamp, self._stamp_id)
        self.last_changed = self._changed[:n_changed]
        return int(n_changed)
