"""From GVD cells to a graph: thinning, vertices at junctions and ends, pruning, subdivision.

1. Thinning (Zhang-Suen, plus removal of staircase corners) leaves 8-connected lines one
   cell wide (the GVD is two cells wide where a corridor's middle falls between cells).
2. Extraction: vertices are line ends (one neighbour) and junctions (three or more;
   touching junction cells form one vertex); edges are the cell paths between them. A
   closed loop with no junction gets a vertex on it.
3. Pruning: a leaf edge whose end lies closer to an obstacle than ``prune_clearance`` is a
   spur into a concave corner (or into a corner of the unexplored region) and is removed,
   repeatedly; components shorter than ``min_component_length`` are dropped.
4. Subdivision: edges are cut so that no straight side between consecutive vertices is
   longer than ``max_side`` (the paper's maximum side length, 2 m) or crosses a non-free
   cell.

The work is done in numba over the list of GVD cells, so its cost follows the GVD's size,
not the map's.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np

_DR = np.array([-1, -1, 0, 1, 1, 1, 0, -1], np.int64)  # N, NE, E, SE, S, SW, W, NW
_DC = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)


@dataclasses.dataclass(frozen=True, kw_only=True)
class GraphConfig:
    """Graph extraction settings.

    Attributes:
        max_side: Longest straight side between consecutive vertices, metres.
        prune_clearance: Leaf branches ending closer than this to an obstacle are pruned, m.
        min_component_length: Graph components shorter than this are dropped, metres.
    """

    max_side: float = 2.0
    prune_clearance: float = 0.25
    min_component_length: float = 0.5


@numba.njit(cache=True)
def _ring(mask, r, c, rows, cols):
    ring = np.zeros(8, np.uint8)
    for k in range(8):
        rr, cc = r + _DR[k], c + _DC[k]
        if 0 <= rr < rows and 0 <= cc < cols and mask[rr * cols + cc]:
            ring[k] = 1
    return ring


@numba.njit(cache=True)
def thin(mask, cells, rows, cols):
    """Thins the lines of ``mask`` (flat uint8) among ``cells`` to one cell, in place.

    Zhang-Suen thinning (two parallel sub-iterations with directional conditions, so lines
    thin from both sides and never erode from their ends), then removal of staircase
    corners: a cell whose only two neighbours are edge-neighbours of it and touch each
    other diagonally.
    """
    delete = np.zeros(len(cells), np.uint8)
    changed = True
    while changed:
        changed = False
        for sub in range(2):
            for i in range(len(cells)):
                c = cells[i]
                delete[i] = 0
                if not mask[c]:
                    continue
                p = _ring(mask, c // cols, c % cols, rows, cols)  # N NE E SE S SW W NW
                b = p.sum()
                if b < 2 or b > 6:
                    continue
                a = 0
                for k in range(8):
                    if p[k] == 0 and p[(k + 1) % 8] == 1:
                        a += 1
                if a != 1:
                    continue
                n_, e, s_, w = p[0], p[2], p[4], p[6]
                if sub == 0 and n_ * e * s_ == 0 and e * s_ * w == 0:
                    delete[i] = 1
                elif sub == 1 and n_ * e * w == 0 and n_ * s_ * w == 0:
                    delete[i] = 1
            for i in range(len(cells)):
                if delete[i]:
                    mask[cells[i]] = 0
                    changed = True
    for c in cells:
        if not mask[c]:
            continue
        p = _ring(mask, c // cols, c % cols, rows, cols)
        if p.sum() != 2:
            continue
        if (p[0] and p[2]) or (p[2] and p[4]) or (p[4] and p[6]) or (p[6] and p[0]):
            mask[c] = 0


@numba.njit(cache=True)
def _step_len(a, b, cols):
    return 1.4142135623730951 if (a // cols != b // cols and a % cols != b % cols) else 1.0


@numba.njit(cache=True)
def extract(mask, cells, rows, cols):
    """Vertices and edges of a thinned line mask.

    Returns:
        vertex_of: int64 per cell (flat), the vertex id of vertex cells, -1 for other cells
            of the mask (undefined off the mask).
        n_vertices: number of vertices.
        edge_a, edge_b, edge_len: int64, int64, float64 arrays (edge endpoints and path
            length in cells).
        path_ptr, path_cells: CSR layout of each edge's cells from a to b (ends included).
    """
    n = len(cells)
    # Per-cell scratch arrays are only ever read at cells of the mask: leave the rest
    # uninitialised (the grid can be large, the GVD is not).
    degree = np.empty(rows * cols, np.int8)
    vertex_of = np.empty(rows * cols, np.int64)
    visited = np.empty(rows * cols, np.uint8)
    for c in cells:
        degree[c] = _ring(mask, c // cols, c % cols, rows, cols).sum()
        vertex_of[c] = -1
        visited[c] = 0
    n_vertices = 0
    stack = np.empty(n + 1, np.int64)
    for c in cells:  # Junction clusters and ends become vertices.
        if not mask[c] or degree[c] == 2 or vertex_of[c] >= 0:
            continue
        vertex_of[c] = n_vertices
        if degree[c] >= 3:
            top = 0
            stack[0] = c
            while top >= 0:
                s = stack[top]
                top -= 1
                for k in range(8):
                    rr, cc = s // cols + _DR[k], s % cols + _DC[k]
                    if 0 <= rr < rows and 0 <= cc < cols:
                        y = rr * cols + cc
                        if mask[y] and degree[y] >= 3 and vertex_of[y] < 0:
                            vertex_of[y] = n_vertices
                            top += 1
                            stack[top] = y
        n_vertices += 1
    edge_a = np.empty(2 * n + 2, np.int64)
    edge_b = np.empty(2 * n + 2, np.int64)
    edge_len = np.empty(2 * n + 2, np.float64)
    path_ptr = np.zeros(2 * n + 3, np.int64)
    path_cells = np.empty(4 * n + 8, np.int64)
    n_edges = 0
    n_path = 0
    for phase in range(2):
        for c in cells:
            if not mask[c]:
                continue
            if phase == 1 and vertex_of[c] < 0 and not visited[c]:
                vertex_of[c] = n_vertices  # A loop without junctions.
                n_vertices += 1
            if vertex_of[c] < 0:
                continue
            for k in range(8):
                rr, cc = c // cols + _DR[k], c % cols + _DC[k]
                if not (0 <= rr < rows and 0 <= cc < cols):
                    continue
                q = rr * cols + cc
                if not mask[q] or visited[q]:
                    continue
                if vertex_of[q] >= 0:
                    if vertex_of[q] > vertex_of[c]:  # Adjacent vertices: a direct edge.
                        edge_a[n_edges] = vertex_of[c]
                        edge_b[n_edges] = vertex_of[q]
                        edge_len[n_edges] = _step_len(c, q, cols)
                        path_cells[n_path] = c
                        path_cells[n_path + 1] = q
                        n_path += 2
                        n_edges += 1
                        path_ptr[n_edges] = n_path
                    continue
                start = n_path
                path_cells[n_path] = c
                n_path += 1
                prev, cur = c, q
                length = _step_len(c, q, cols)
                first = True
                while True:
                    path_cells[n_path] = cur
                    n_path += 1
                    if vertex_of[cur] >= 0:
                        break
                    visited[cur] = 1
                    nxt = -1
                    for j in range(8):
                        r2, c2 = cur // cols + _DR[j], cur % cols + _DC[j]
                        if 0 <= r2 < rows and 0 <= c2 < cols:
                            y = r2 * cols + c2
                            if not mask[y] or y == prev:
                                continue
                            if first and vertex_of[y] == vertex_of[c]:
                                continue  # Another cell of the vertex we left.
                            if vertex_of[y] >= 0 or not visited[y]:
                                if nxt < 0 or vertex_of[y] >= 0:
                                    nxt = y
                    first = False
                    if nxt < 0:
                        break
                    length += _step_len(cur, nxt, cols)
                    prev, cur = cur, nxt
                if vertex_of[cur] < 0:
                    n_path = start  # Dead end without a vertex (cannot happen): drop.
                    continue
                edge_a[n_edges] = vertex_of[c]
                edge_b[n_edges] = vertex_of[cur]
                edge_len[n_edges] = length
                n_edges += 1
                path_ptr[n_edges] = n_path
    return (vertex_of, n_vertices, edge_a[:n_edges], edge_b[:n_edges], edge_len[:n_edges],
            path_ptr[:n_edges + 1], path_cells[:n_path])


@dataclasses.dataclass(frozen=True)
class GvdGraph:
    """A graph on the GVD.

    Attributes:
        positions: (n, 2) vertex positions (row, col) in cells (floats: junction clusters
            are averaged).
        edges: (m, 2) int vertex pairs (i < j), each straight side collision-free.
        lengths: (m,) Euclidean side lengths in cells.
        clearance: (n,) distance from each vertex to its nearest obstacle, cells.
    """

    positions: np.ndarray
    edges: np.ndarray
    lengths: np.ndarray
    clearance: np.ndarray


@numba.njit(cache=True)
def segment_free_cells(free, r0, c0, r1, c1):
    """Kernel of :func:`segment_is_free` for other numba code (float cell coordinates)."""
    n = int(math.ceil(2.0 * max(abs(r1 - r0), abs(c1 - c0)))) + 1
    rows, cols = free.shape
    for i in range(n + 1):
        t = i / n if n > 0 else 0.0
        r = int(math.floor(r0 + (r1 - r0) * t + 0.5))
        c = int(math.floor(c0 + (c1 - c0) * t + 0.5))
        if r < 0 or r >= rows or c < 0 or c >= cols or not free[r, c]:
            return False
    return True


def segment_is_free(free: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """True if every cell the straight segment from cell ``a`` to ``b`` (row, col, cell
    centres at integers) passes through is free, sampled every half cell."""
    return bool(segment_free_cells(free, float(a[0]), float(a[1]), float(b[0]), float(b[1])))


def build_graph(voronoi: np.ndarray, distance2: np.ndarray, free: np.ndarray,
                resolution: float, config: GraphConfig | None = None) -> GvdGraph:
    """Extracts, prunes and subdivides the graph of a GVD.

    Args:
        voronoi: (rows, cols) bool GVD cells (not modified).
        distance2: (rows, cols) squared distance to the nearest obstacle, cells^2.
        free: (rows, cols) bool cells a straight side may cross.
        resolution: Cell side in metres.
        config: Extraction settings.
    """
    config = config or GraphConfig()
    rows, cols = voronoi.shape
    cells = np.flatnonzero(voronoi.reshape(-1))
    mask = np.zeros(rows * cols, np.uint8)
    mask[cells] = 1
    thin(mask, cells, rows, cols)
    cells = cells[mask[cells] == 1]
    vertex_of, n_v, ea, eb, elen, ptr, path = extract(mask, cells, rows, cols)
    if n_v == 0:
        return GvdGraph(np.zeros((0, 2)), np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0))
    # Vertex positions: the mean of their cells.
    vcells = cells[vertex_of[cells] >= 0]
    vid = vertex_of[vcells]
    counts = np.bincount(vid, minlength=n_v).astype(float)
    pos = np.column_stack([np.bincount(vid, vcells // cols, n_v),
                           np.bincount(vid, vcells % cols, n_v)]) / counts[:, None]
    dist2 = distance2.reshape(-1)
    vclear = np.bincount(vid, np.sqrt(dist2[vcells]), n_v) / counts
    alive = _prune(n_v, ea, eb, elen, vclear, config.prune_clearance / resolution,
                   config.min_component_length / resolution)
    return _subdivide(pos, vclear, ea, eb, ptr, path, alive, dist2, free, cols,
                      config.max_side / resolution)


@numba.njit(cache=True)
def _prune(n_v, ea, eb, elen, vclear, min_clear, min_length):
    """Which edges survive leaf-spur pruning and small-component removal."""
    m = len(ea)
    alive = np.ones(m, np.bool_)
    degree = np.zeros(n_v, np.int64)
    for e in range(m):
        degree[ea[e]] += 1
        degree[eb[e]] += 1
    # Incidence lists (CSR).
    ptr = np.zeros(n_v + 1, np.int64)
    for v in range(n_v):
        ptr[v + 1] = ptr[v] + degree[v]
    fill = ptr[:-1].copy()
    inc = np.empty(2 * m, np.int64)
    for e in range(m):
        inc[fill[ea[e]]] = e
        fill[ea[e]] += 1
        inc[fill[eb[e]]] = e
        fill[eb[e]] += 1
    stack = np.empty(n_v + 2 * m + 1, np.int64)
    top = -1
    for v in range(n_v):
        if degree[v] == 1 and vclear[v] < min_clear:
            top += 1
            stack[top] = v
    while top >= 0:
        leaf = stack[top]
        top -= 1
        if degree[leaf] != 1 or vclear[leaf] >= min_clear:
            continue
        e = -1
        for k in range(ptr[leaf], ptr[leaf + 1]):
            if alive[inc[k]]:
                e = inc[k]
        other = eb[e] if ea[e] == leaf else ea[e]
        if degree[other] <= 1 or other == leaf:
            continue  # An isolated segment or loop: left to the component test.
        alive[e] = False
        degree[leaf] -= 1
        degree[other] -= 1
        if degree[other] == 1 and vclear[other] < min_clear:
            top += 1
            stack[top] = other
    parent = np.arange(n_v)
    for e in range(m):
        if alive[e]:
            a, b = ea[e], eb[e]
            while parent[a] != a:
                a = parent[a]
            while parent[b] != b:
                b = parent[b]
            if a != b:
                parent[b] = a
    root = np.empty(n_v, np.int64)
    for v in range(n_v):
        a = v
        while parent[a] != a:
            a = parent[a]
        root[v] = a
    total = np.zeros(n_v)
    for e in range(m):
        if alive[e]:
            total[root[ea[e]]] += elen[e]
    for e in range(m):
        if alive[e] and total[root[ea[e]]] < min_length:
            alive[e] = False
    return alive


@numba.njit(cache=True)
def _subdivide_edges(pos, clear, ea, eb, ptr, path, alive, dist2, free, cols, max_side):
    """Cuts every alive edge's path into straight, free sides no longer than ``max_side``.

    Returns (positions, clearance, edges): vertices (the given ones, then new ones placed
    on path cells) and the (a, b) vertex pairs of the sides.
    """
    n_v = len(pos)
    cap = n_v + len(path) + 1
    out_pos = np.empty((cap, 2))
    out_clear = np.empty(cap)
    out_pos[:n_v] = pos
    out_clear[:n_v] = clear
    n_out = n_v
    edges = np.empty((2 * len(path) + len(ea) + 1, 2), np.int64)
    n_edges = 0
    stack = np.empty((len(path) + 2, 4), np.int64)  # (first, last) path index, (va, vb)
    for e in range(len(ea)):
        if not alive[e] or ea[e] == eb[e] and ptr[e + 1] - ptr[e] <= 2:
            continue
        cells = path[ptr[e]:ptr[e + 1]]
        m = len(cells)
        along = np.zeros(m)
        for i in range(1, m):
            along[i] = along[i - 1] + _step_len(cells[i - 1], cells[i], cols)
        top = 0
        stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = 0, m - 1, ea[e], eb[e]
        while top >= 0:
            i0, i1, va, vb = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
            top -= 1
            pa, pb = out_pos[va], out_pos[vb]
            span = math.hypot(pb[0] - pa[0], pb[1] - pa[1])
            if i1 - i0 <= 1 or (span <= max_side and va != vb and
                                segment_free_cells(free, pa[0], pa[1], pb[0], pb[1])):
                if va != vb:
                    edges[n_edges, 0] = min(va, vb)
                    edges[n_edges, 1] = max(va, vb)
                    n_edges += 1
                continue
            length = along[i1] - along[i0]
            pieces = max(2, int(math.ceil(length / max_side)))
            prev_i, prev_v = i0, va
            for k in range(1, pieces + 1):
                if k < pieces:
                    target = along[i0] + length * k / pieces
                    cut = i0 + 1
                    while cut < i1 - 1 and along[cut] < target:
                        cut += 1
                    if cut <= prev_i:
                        continue
                    c = cells[cut]
                    out_pos[n_out, 0] = c // cols
                    out_pos[n_out, 1] = c % cols
                    out_clear[n_out] = math.sqrt(dist2[c])
                    v = n_out
                    n_out += 1
                else:
                    cut, v = i1, vb
                top += 1
                stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = prev_i, cut, prev_v, v
                prev_i, prev_v = cut, v
    return out_pos[:n_out], out_clear[:n_out], edges[:n_edges]


def _subdivide(pos, vclear, ea, eb, ptr, path, alive, dist2, free, cols, max_side):
    positions, clearance, edges = _subdivide_edges(pos, vclear, ea, eb, ptr, path, alive,
                                                   dist2, free, cols, float(max_side))
    edges = np.unique(edges, axis=0) if len(edges) else edges.reshape(0, 2)
    used = np.zeros(len(positions), bool)
    used[edges.ravel()] = True
    remap = np.cumsum(used) - 1
    edges = remap[edges]
    positions = positions[used]
    lengths = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    return GvdGraph(positions, edges, lengths, clearance[used])
