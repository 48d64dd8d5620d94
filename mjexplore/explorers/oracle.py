"""The oracle: a ground-truth coverage planner, the bound every explorer is read against.

It knows the map it explores. Candidate viewpoints lie on a ``spacing`` lattice of the
cells the robot's centre may occupy (on the ground truth, with ``clearance`` to walls);
what each one sees is ray cast on the ground truth with the episode's lidar range and
occlusion (``rays`` rays, the cells each ray crosses up to and including the first wall,
as the mapper marks them). At every decision it:

1. counts the observable cells still unknown in the map and how many of them must still be
   seen to reach the target ratio plus ``margin``;
2. keeps the viewpoints of its previous plan that still see at least ``min_gain`` of those
   cells and adds viewpoints greedily by new cells seen (lazy greedy set cover) until the
   plan sees enough;
3. orders them as an open tour from the robot over path distances on the ground truth
   (OR-Tools, :func:`mjexplore.navigation.tour.open_tour`, warm-started from the previous
   order);
4. drops the viewpoints the tour makes redundant, the largest saving in tour length first:
   what the others see, and what the robot sees on the way between them (the views of the
   lattice points along the path graph's shortest paths, every ``path_sample`` metres);
5. drives to the first with the same navigator as every explorer, on a costmap of the
   ground truth.

Viewpoints whose cells got seen on the way drop out at the next decision, and a viewpoint
whose view the drive uncovered is given up at once (``goal_open``). The cells the ray
casting counts as visible but the lidar misses (grazing beams, gaps between beams at long
range) are planned for again from other viewpoints; when no viewpoint sees any needed cell
it answers None and the episode finishes with the nearest frontier (its fallback).

:meth:`OracleExplorer.expert_choice` answers, for any exploration state, which of a set of
candidate goals (e.g. the TER's frontier nodes) it would pick: the one closest by path to
the first viewpoint of its tour, so that learned explorers can imitate it.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
from scipy.spatial import cKDTree

from mjexplore.episode.explorer import ExplorationState
from mjexplore.mapping.metrics import observable_ground_truth
from mjexplore.maps import traversal_start
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.navigation.tour import CoarseGraph, TourConfig, open_tour, tour_length
from mjexplore.topology.gvd import DynamicGVD


@numba.njit(cache=True)
def _visible_cells(opaque, wanted, r0, c0, reach, n_rays, stamp, stamp_id, out):
    """Cells seen from the centre of cell (r0, c0), listed in ``out``; returns how many.

    Each ray walks the cells it crosses (Amanatides-Woo) up to ``reach`` cells, stopping
    after the first opaque cell; only cells flagged in ``wanted`` are listed, each once
    (``stamp`` holds ``stamp_id`` for the cells already listed).
    """
    rows, cols = opaque.shape
    n = 0
    x0 = c0 + 0.5
    y0 = r0 + 0.5
    for i in range(n_rays):
        a = 2.0 * math.pi * (i + 0.5) / n_rays
        cx, cy, step_x, step_y, t_max_x, t_max_y, t_dx, t_dy = traversal_start(
            x0, y0, math.cos(a), math.sin(a))
        t = 0.0
        while t <= reach and 0 <= cy < rows and 0 <= cx < cols:
            k = cy * cols + cx
            if wanted[k] and stamp[k] != stamp_id:
                stamp[k] = stamp_id
                out[n] = k
                n += 1
            if opaque[cy, cx]:
                break
            if t_max_x < t_max_y:
                t = t_max_x
                cx += step_x
                t_max_x += t_dx
            else:
                t = t_max_y
                cy += step_y
                t_max_y += t_dy
    return n


@numba.njit(cache=True)
def _gains(ptr, idx, need, chosen):
    """Cells of ``need`` each viewpoint sees (-1 for viewpoints not in ``chosen``)."""
    n = len(ptr) - 1
    out = np.full(n, -1, np.int64)
    for i in range(n):
        if chosen[i]:
            g = 0
            for j in range(ptr[i], ptr[i + 1]):
                g += need[idx[j]]
            out[i] = g
    return out


@numba.njit(cache=True)
def _uncovered(ptr, idx, need, covered, i):
    """Cells of ``need`` viewpoint ``i`` sees that ``covered`` lacks."""
    g = 0
    for j in range(ptr[i], ptr[i + 1]):
        if need[idx[j]] and not covered[idx[j]]:
            g += 1
    return g


@numba.njit(cache=True)
def _greedy_cover(ptr, idx, need, allowed, selected, required, min_gain, upper):
    """Lazy greedy set cover: viewpoints (flagged in ``allowed``) are added to ``selected``
    in order of the most cells of ``need`` not yet covered, until ``required`` cells are
    covered or no viewpoint adds ``min_gain``. ``selected`` viewpoints count as chosen
    already; ``upper`` bounds each viewpoint's gain from above (e.g. its count of cells of
    ``need``): gains are evaluated lazily, so the pick is the lowest-index viewpoint of
    greatest gain, as with exact gains. Returns the added viewpoints in order and the
    number of cells covered."""
    covered = np.zeros(len(need), np.bool_)
    total = 0
    for i in range(len(ptr) - 1):
        if selected[i]:
            for j in range(ptr[i], ptr[i + 1]):
                k = idx[j]
                if need[k] and not covered[k]:
                    covered[k] = True
                    total += 1
    bound = np.where(allowed & ~selected, upper, -1)
    added = []
    while total < required:
        i = np.argmax(bound)
        if bound[i] < min_gain:
            break
        g = _uncovered(ptr, idx, need, covered, i)
        if g < bound[i]:
            bound[i] = g  # Stale: gains only shrink, so re-queue with the true value.
            continue
        for j in range(ptr[i], ptr[i + 1]):
            if need[idx[j]]:
                covered[idx[j]] = True
        total += g
        bound[i] = -1
        added.append(i)
    return added, total


@numba.njit(cache=True)
def _viewers(ptr, idx, cells):
    """The transpose of the view lists: for each cell, the viewpoints that see it (CSR
    ``out_ptr`` over ``cells`` cells, ``out_idx`` viewpoint indices, ascending)."""
    out_ptr = np.zeros(cells + 1, np.int64)
    for j in range(len(idx)):
        out_ptr[idx[j] + 1] += 1
    for k in range(cells):
        out_ptr[k + 1] += out_ptr[k]
    fill = out_ptr[:-1].copy()
    out_idx = np.empty(len(idx), np.int32)
    for i in range(len(ptr) - 1):
        for j in range(ptr[i], ptr[i + 1]):
            out_idx[fill[idx[j]]] = i
            fill[idx[j]] += 1
    return out_ptr, out_idx


@numba.njit(cache=True)
def _recount(viewer_ptr, viewer_idx, cells, delta, counts):
    """Adds ``delta`` to the count of every viewpoint that sees each of ``cells``."""
    for k in cells:
        for j in range(viewer_ptr[k], viewer_ptr[k + 1]):
            counts[viewer_idx[j]] += delta


@numba.njit(cache=True)
def _covered(ptr, idx, need, views, stamp, stamp_id):
    """How many cells of ``need`` the ``views`` see together (``stamp``: scratch, one entry
    per cell, never holding ``stamp_id`` before the call)."""
    total = 0
    for i in views:
        for j in range(ptr[i], ptr[i + 1]):
            k = idx[j]
            if need[k] and stamp[k] != stamp_id:
                stamp[k] = stamp_id
                total += 1
    return total


@numba.njit(cache=True, parallel=True)
def _keep_needed(ptr, idx, need):
    """The view lists with only the cells of ``need`` left (CSR ``ptr``, ``idx``); one
    viewpoint per thread."""
    n = len(ptr) - 1
    count = np.zeros(n, np.int64)
    for i in numba.prange(n):
        c = 0
        for j in range(ptr[i], ptr[i + 1]):
            c += need[idx[j]]
        count[i] = c
    out_ptr = np.zeros_like(ptr)
    out_ptr[1:] = np.cumsum(count)
    out_idx = np.empty(out_ptr[-1], idx.dtype)
    for i in numba.prange(n):
        k = out_ptr[i]
        for j in range(ptr[i], ptr[i + 1]):
            if need[idx[j]]:
                out_idx[k] = idx[j]
                k += 1
    return out_ptr, out_idx


@dataclasses.dataclass
class _Views:
    """Candidate viewpoints and what each sees (CSR lists of flat cell indices)."""

    points: np.ndarray  # (n, 2) positions in the map frame, metres.
    ptr: np.ndarray  # (n + 1,) int64.
    idx: np.ndarray  # (nnz,) int32.
    observable: np.ndarray  # (cells,) bool: the reference's known cells.


def _candidates(candidates, valid) -> tuple[np.ndarray, np.ndarray]:
    """(k, 2) float candidate goals and their (k,) bool validity (all valid by default)."""
    candidates = np.asarray(candidates, float).reshape(-1, 2)
    return candidates, (np.ones(len(candidates), bool) if valid is None
                        else np.asarray(valid, bool))


LOOKAHEAD_MARGIN = 0.012
"""The oracle's planned coverage above the target when it answers by lookahead."""


class OracleExplorer:
    """Ground-truth coverage planner (the bound).

    Args:
        spacing: Lattice spacing of candidate viewpoints, metres.
        clearance: Least distance from a viewpoint to a wall, metres.
        rays: Rays cast per viewpoint (the lidar sweeps new angles as the robot moves, so
            more than one scan's beams).
        margin: Planned coverage above ``target_ratio``, for the cells the lidar misses.
        min_gain: Least number of needed cells a viewpoint must see to stay in the plan.
        path_sample: Spacing of the points along the tour's paths whose views count as
            seen on the way, metres.
        prune_tries: Viewpoints tried for removal per pruning round (largest saving first).
        tour: Tour solver settings.
    """

    name = "oracle"

    plans_on_ground_truth = True

    def __init__(self, spacing: float = 0.5, clearance: float = 0.35, rays: int = 720,
                 margin: float = 0.004, min_gain: int = 12, path_sample: float = 1.0,
                 prune_tries: int = 4, tour: TourConfig | None = None) -> None:
        self.spacing = spacing
        self.clearance = clearance
        self.rays = rays
        self.margin = margin
        self.min_gain = min_gain
        self.path_sample = path_sample
        self.prune_tries = prune_tries
        self.tour_config = tour or TourConfig(time_limit=1.0)

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self.views: _Views | None = None
        self.graph: CoarseGraph | None = None
        self.plan: list[int] = []  # Viewpoint indices in tour order.
        self.current: int | None = None

    def ground_truth_costmap(self, state: ExplorationState) -> Costmap:
        """The planner's costmap of the ground truth (unknown ground-truth cells block)."""
        gt = state.ground_truth
        assert gt is not None  # Asked only with the ground truth (prepare, the engine).
        gvd = DynamicGVD(gt.shape)
        gvd.update(gt.occupied | (gt.data < 0))
        return Costmap(gt, gvd.distance2, PlannerConfig())

    # ------------------------------------------------------------------ planning

    def prepare(self, state: ExplorationState) -> None:
        """Candidate viewpoints, their views and the path graph (once per episode)."""
        if state.ground_truth is None:
            raise ValueError("the oracle needs the ground truth (ExplorationState.ground_truth)")
        gt = state.ground_truth
        costmap = self.ground_truth_costmap(state)
        self.graph = CoarseGraph(gt, costmap.traversable)
        observable = observable_ground_truth(gt).known.reshape(-1)
        cand = np.argwhere(self.viewpoint_cells(costmap, state.pose))
        seen = self.cast_views(gt, cand, observable, state.sensor_range)
        self.set_views(gt, cand, observable, seen, observable)

    def viewpoint_cells(self, costmap: Costmap, pose: np.ndarray) -> np.ndarray:
        """(rows, cols) bool: the ``spacing`` lattice's cells of ``costmap`` that a path
        from ``pose`` reaches and that lie at least ``clearance`` from its walls."""
        grid = costmap.grid
        reachable = (costmap.distances_from(pose[:2]) < np.inf).reshape(grid.shape)
        clear = np.sqrt(costmap._dist2.reshape(grid.shape)) * grid.resolution
        step = max(1, int(round(self.spacing / grid.resolution)))
        lattice = np.zeros(grid.shape, bool)
        lattice[::step, ::step] = True
        return reachable & (clear >= self.clearance) & lattice

    def cast_views(self, plan_map, cand: np.ndarray, wanted: np.ndarray,
                   sensor_range: float) -> list[np.ndarray]:
        """The flat indices of the cells of ``wanted`` each candidate viewpoint (an (n, 2)
        int (row, col) array) sees on ``plan_map``, whose non-free cells block the view."""
        opaque = ~plan_map.free
        reach = sensor_range / plan_map.resolution
        stamp = np.zeros(plan_map.data.size, np.int64)
        buf = np.empty(plan_map.data.size, np.int64)
        seen = []
        for i, (r, c) in enumerate(cand):
            n = _visible_cells(opaque, wanted, r, c, reach, self.rays, stamp, i + 1, buf)
            seen.append(buf[:n].copy())
        return seen

    def set_views(self, plan_map, cand: np.ndarray, observable: np.ndarray,
                  seen: list[np.ndarray], needed: np.ndarray) -> None:
        """Sets the candidate viewpoints and what they see, and the plan's bookkeeping
        (``self.graph`` must be the path graph of ``plan_map``).

        Args:
            plan_map: The map planned on.
            cand: (n, 2) int (row, col) cells of the candidate viewpoints.
            observable: (cells,) bool, the cells the plan must see (or leave within the
                target's slack).
            seen: Per viewpoint, the flat indices of the observable cells it sees
                (:meth:`cast_views`).
            needed: (cells,) bool, the cells that may still be needed (``seen`` is cut down
                to them).
        """
        assert self.graph is not None  # The caller sets the path graph first.
        ptr = np.zeros(len(seen) + 1, np.int64)
        ptr[1:] = np.cumsum([len(s) for s in seen])
        idx = (np.concatenate(seen) if seen else np.zeros(0, np.int64)).astype(np.int32)
        if not needed.all():
            ptr, idx = _keep_needed(ptr, idx, needed)
        self.views = _Views(plan_map.cell_to_world(cand).reshape(-1, 2), ptr, idx, observable)
        # Each viewpoint's count of needed cells, kept up to date cell by cell as the map
        # fills in (through the transposed lists): the cover's upper bounds without a pass
        # over every list at every decision.
        self._viewer_ptr, self._viewer_idx = _viewers(ptr, idx, plan_map.data.size)
        self._need_count = np.diff(ptr)
        self._needed = needed.copy()
        self._stamp, self._stamp_id = np.zeros(plan_map.data.size, np.int64), 0
        self._listed = int(needed.sum())  # Unknown cells when the lists were last cut.
        # The viewpoint standing for each node of the path graph (the nearest within one
        # lattice step; -1 if none): what the robot sees while it drives through the node.
        self._view_tree = cKDTree(self.views.points) if len(cand) else None
        if self._view_tree is not None:
            near, which = self._view_tree.query(self.graph.centres,
                                                distance_upper_bound=self.spacing)
            self._node_view = np.where(np.isfinite(near), which, -1)
        else:
            self._node_view = np.full(len(self.graph.centres), -1)

    def _need(self, state: ExplorationState) -> tuple[np.ndarray, int]:
        """The observable cells still unknown, and how many of them must still be seen.

        Mapped cells stay mapped, so once a quarter of the cells the view lists held are
        known, the lists are cut down to the unknown ones: later passes over them are shorter.
        """
        views = self.views
        assert views is not None  # Set by prepare.
        need = views.observable & self.unknown_cells(state)
        for cells, delta in ((self._needed & ~need, -1), (need & ~self._needed, 1)):
            _recount(self._viewer_ptr, self._viewer_idx, np.flatnonzero(cells), delta,
                     self._need_count)
        self._needed = need
        total = int(views.observable.sum())
        unseen = int(need.sum())
        if 4 * unseen <= 3 * self._listed:
            views.ptr, views.idx = _keep_needed(views.ptr, views.idx, need)
            self._listed = unseen
        return need, max(1, min(self.required(state, total, unseen), unseen))

    def unknown_cells(self, state: ExplorationState) -> np.ndarray:
        """(cells,) bool: the cells of the map planned on that the robot has not mapped."""
        return state.grid.data.reshape(-1) < 0

    def required(self, state: ExplorationState, total: int, unseen: int) -> int:
        """How many of the ``unseen`` needed cells the plan must see: enough for the target
        ratio plus ``margin`` of the ``total`` observable cells."""
        return math.ceil((state.target_ratio + self.margin) * total) - (total - unseen)

    def replan(self, state: ExplorationState) -> list[int]:
        """Re-solves the plan for the state; returns the viewpoints in tour order."""
        if self.views is None:
            self.prepare(state)
        assert self.views is not None and self.graph is not None  # Set by prepare.
        views = self.views
        need, required = self._need(state)
        n = len(views.points)
        allowed = state.allowed(views.points) if n else np.zeros(0, bool)
        kept = np.zeros(n, bool)
        if self.plan:
            prev = np.array(self.plan, np.int64)
            gains = _gains(views.ptr, views.idx, need, np.isin(np.arange(n), prev))[prev]
            kept[prev[(gains >= self.min_gain) & allowed[prev]]] = True
        added = []
        if self._count(np.flatnonzero(kept).tolist(), need) < required:
            added, _ = _greedy_cover(views.ptr, views.idx, need, allowed, kept, required,
                                     self.min_gain, self._need_count)
        plan = [i for i in self.plan if kept[i]] + list(added)
        if not plan:
            self.plan = []
            return self.plan
        points = np.vstack([state.pose[:2], self.views.points[plan]])
        distance = self.graph.distance_matrix(points)
        order = self._order(plan, distance)
        order = self._prune(plan, order, distance, need, required,
                            self.graph.node_of(points))
        self.plan = [plan[j - 1] for j in order]
        return self.plan

    def planned_coverage(self, state: ExplorationState) -> float:
        """The exploration ratio the current plan would reach: the observable cells known
        in ``state.grid`` plus those its tour sees (at the viewpoints and on the way), over
        all observable cells."""
        need, _ = self._need(state)
        assert self.views is not None and self.graph is not None  # _need needs them too.
        points = np.vstack([state.pose[:2], self.views.points[self.plan]])
        order = list(range(1, len(self.plan) + 1))
        seen = self._tour_sees(self.plan, order, self.graph.node_of(points), need)
        total = int(self.views.observable.sum())
        return (total - int(need.sum()) + seen) / total

    def _order(self, plan: list[int], distance: np.ndarray) -> list[int]:
        """The plan (places 1.. of ``distance``) as an open tour from place 0."""
        previous = {v: k for k, v in enumerate(self.plan)}
        warm = sorted(range(1, len(plan) + 1), key=lambda j: previous.get(plan[j - 1], len(plan)))
        return open_tour(distance, self.tour_config, initial=warm)

    def _prune(self, plan: list[int], order: list[int], distance: np.ndarray,
               need: np.ndarray, required: int, nodes: np.ndarray) -> list[int]:
        """Drops viewpoints the rest of the tour makes redundant, the one whose removal
        shortens the tour most first, while the tour still sees ``required`` cells: at its
        viewpoints, and on the way between them (``nodes``: each place's path-graph node,
        place 0 the start)."""
        order = list(order)
        d = np.where(np.isfinite(distance), distance, 1e5)
        while len(order) > 1:
            ends = [0, *order, -1]
            saving = np.array([d[a, b] + (d[b, c] - d[a, c] if c >= 0 else 0.0)
                               for a, b, c in zip(ends, ends[1:], ends[2:])])
            for k in np.argsort(-saving, kind="stable")[:self.prune_tries]:
                trial = order[:k] + order[k + 1:]
                if self._tour_sees(plan, trial, nodes, need) >= required:
                    order = trial
                    break
            else:
                break
        return order

    def _tour_sees(self, plan: list[int], order: list[int], nodes: np.ndarray,
                   need: np.ndarray) -> int:
        """Cells of ``need`` seen at the tour's viewpoints and from the viewpoints standing
        for every ``path_sample``-th node of the paths between them."""
        assert self.graph is not None  # Tours are made after prepare.
        seen = [plan[j - 1] for j in order]
        step = max(1, int(round(self.path_sample / (self.graph.block *
                                                    self.graph.grid.resolution))))
        for a, b in zip([0, *order], order):
            if nodes[a] >= 0 and nodes[b] >= 0:
                along = self._node_view[self.graph.path(int(nodes[a]), int(nodes[b]))[::step]]
                seen.extend(along[along >= 0].tolist())
        return self._count(seen, need)

    def _count(self, views: list[int], need: np.ndarray) -> int:
        """Cells of ``need`` the viewpoints see together."""
        assert self.views is not None  # Counts are made after prepare.
        self._stamp_id += 1
        return _covered(self.views.ptr, self.views.idx, need,
                        np.unique(np.array(views, np.int64)), self._stamp, self._stamp_id)

    # ------------------------------------------------------------------ explorer

    def goal_open(self, grid) -> bool | None:
        """The current viewpoint stays worth reaching while it still sees ``min_gain``
        observable cells unknown in ``grid``; None for a fallback frontier goal (the
        runner's frontier test applies)."""
        if self.current is None:
            return None
        views = self.views
        assert views is not None  # The current viewpoint is one of them.
        cells = views.idx[views.ptr[self.current]:views.ptr[self.current + 1]]
        return bool((grid.data.reshape(-1)[cells] < 0).sum() >= self.min_gain)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        plan = self.replan(state)
        assert self.views is not None  # Set by replan.
        if plan:
            self.current = plan[0]
            return self.views.points[plan[0]].copy()
        # Nothing a viewpoint sees is needed, yet the episode goes on: what is left are
        # cells the ray casting counted as seen that the lidar missed, which the episode's
        # nearest-frontier fallback picks up.
        self.current = None
        return None

    def expert_choice(self, state: ExplorationState, candidates: np.ndarray,
                      valid: np.ndarray | None = None) -> int:
        """Which candidate goal the oracle would pick: the valid one closest by path on the
        ground truth to the first viewpoint of its tour (nearest to the robot without a
        tour), e.g. among the TER's frontier nodes.

        Args:
            state: The exploration state.
            candidates: (k, 2) candidate goals in the ``map`` frame, metres.
            valid: (k,) bool, the candidates that may be chosen (default: all).

        Returns:
            The index of the chosen candidate, or -1 if none is valid.
        """
        candidates, valid = _candidates(candidates, valid)
        if not valid.any():
            return -1
        plan = self.replan(state)
        assert self.views is not None and self.graph is not None  # Set by replan.
        target = self.views.points[plan[0]] if plan else np.asarray(state.pose[:2], float)
        d = self.graph.distance_matrix(np.vstack([target, candidates]))[0, 1:]
        d = np.where(valid, d, np.inf)
        if not np.isfinite(d).any():  # Off the path graph: fall back to straight lines.
            d = np.where(valid, np.linalg.norm(candidates - target, axis=1), np.inf)
        return int(np.argmin(d))

    def expert_lookahead(self, state: ExplorationState, candidates: np.ndarray,
                         valid: np.ndarray | None = None, baseline: int | None = None,
                         gain_m: float = 0.0) -> int:
        """Which candidate goal leaves the shortest ground-truth coverage tour: the valid
        one minimising the path from the robot to it plus an open tour from it over the
        viewpoints of the oracle's plan it does not make redundant (one step of lookahead
        with the oracle's tour as the cost to go).

        A viewpoint counts as made redundant when fewer than ``min_gain`` of its needed
        cells stay unseen after the candidate's own view (the lattice viewpoint nearest the
        candidate) and the views along the path to it, as :meth:`_tour_sees` counts them.

        The plan covers only the target ratio plus ``margin``; with the default margin the
        cells it leaves out near the end get planned for again after the robot has left
        them, and the lookahead sends it back and forth (one validation layout: 118.6 s
        against the prior's 45.9). :func:`lookahead_expert` builds the oracle with
        ``LOOKAHEAD_MARGIN`` (51.1 s there).

        Args:
            state: The exploration state.
            candidates: (k, 2) candidate goals in the ``map`` frame, metres.
            valid: (k,) bool, the candidates that may be chosen (default: all).
            baseline: A valid candidate to keep (another explorer's choice) unless the best
                one's path plus tour is shorter by more than ``gain_m``.
            gain_m: Metres the best candidate must save over ``baseline``.

        Returns:
            The index of the chosen candidate, or -1 if none is valid.
        """
        candidates, valid = _candidates(candidates, valid)
        if not valid.any():
            return -1
        plan = self.replan(state)
        if not plan:
            return self.expert_choice(state, candidates, valid) if baseline is None else baseline
        views = self.views
        # Set by replan; the plan's viewpoints are in the tree.
        assert views is not None and self.graph is not None and self._view_tree is not None
        need, _ = self._need(state)
        k = len(candidates)
        points = np.vstack([state.pose[:2], candidates, views.points[plan]])
        distance = self.graph.distance_matrix(points)
        nodes = self.graph.node_of(points)
        own_view = self._view_tree.query(candidates)[1]
        step = max(1, int(round(self.path_sample / (self.graph.block *
                                                    self.graph.grid.resolution))))
        config = dataclasses.replace(self.tour_config, time_limit=0.05, guided=False)
        cost = np.full(k, np.inf)
        covered = np.zeros(need.size, bool)  # Cleared after each candidate.
        for a in np.flatnonzero(valid & np.isfinite(distance[0, 1:k + 1])):
            seen = [int(own_view[a])]
            if nodes[0] >= 0 and nodes[1 + a] >= 0:
                along = self._node_view[self.graph.path(int(nodes[0]), int(nodes[1 + a]))[::step]]
                seen.extend(along[along >= 0].tolist())
            cells = np.concatenate([views.idx[views.ptr[v]:views.ptr[v + 1]] for v in set(seen)])
            covered[cells] = True
            left = [j for j, v in enumerate(plan)
                    if _uncovered(views.ptr, views.idx, need, covered, v) >= self.min_gain]
            covered[cells] = False
            places = np.array([1 + a, *(1 + k + j for j in left)])
            sub = np.minimum(distance[np.ix_(places, places)], 1e5)
            order = open_tour(sub, config)
            cost[a] = distance[0, 1 + a] + tour_length(sub, order)
        if not np.isfinite(cost).any():
            return self.expert_choice(state, candidates, valid) if baseline is None else baseline
        best = int(np.argmin(cost))
        if baseline is not None and not cost[best] < cost[baseline] - gain_m:
            return int(baseline)
        return best


def lookahead_expert() -> OracleExplorer:
    """An oracle to answer by :meth:`OracleExplorer.expert_lookahead` (plans
    ``LOOKAHEAD_MARGIN`` above the target ratio)."""
    return OracleExplorer(margin=LOOKAHEAD_MARGIN)
