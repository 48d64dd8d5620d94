"""The oracle: a planner that knows the ground truth, as a practical lower bound.

It plans a tour of viewpoints that together see (nearly) all observable free space and
wall surfaces: candidates on a ``spacing`` lattice in the robot's configuration space,
their views by ray casting on the ground truth at the lidar's range, chosen one after
another by new cells seen per metre of path from the previous one (a greedy covering
tour, with path distances on the ground truth), then reordered by 2-opt so that the tour
does not cross back and forth. It drives the tour on a costmap of the ground truth; viewpoints whose view is already mostly
known are skipped. Cells the ray casting counted as seen but the lidar missed are picked up
at the end by the nearest frontier. No explorer without the ground truth can expect to do better by much.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mjexplore.explorers.base import ExplorationState, register
from mjexplore.explorers.nearest import NearestFrontier
from mjexplore.mapping.metrics import observable_ground_truth
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.topology.gvd import DynamicGVD


@numba.njit(cache=True)
def _visible(opaque, r0, c0, reach, n_rays, out, stamp, stamp_id):
    """Marks (in ``stamp``) the cells seen from (r0, c0); returns how many, listed in out."""
    rows, cols = opaque.shape
    n = 0
    for i in range(n_rays):
        a = 2.0 * math.pi * i / n_rays
        dr, dc = math.sin(a), math.cos(a)
        steps = int(reach * 2)
        for s in range(steps + 1):
            t = s * 0.5
            r = int(math.floor(r0 + 0.5 + dr * t))
            c = int(math.floor(c0 + 0.5 + dc * t))
            if r < 0 or r >= rows or c < 0 or c >= cols:
                break
            k = r * cols + c
            if stamp[k] != stamp_id:
                stamp[k] = stamp_id
                out[n] = k
                n += 1
            if opaque[r, c]:
                break
    return n


@register("oracle")
class OracleExplorer:
    """Args:
        spacing: Lattice spacing of candidate viewpoints, metres.
        coverage: Share of all observable cells that must be seen once the tour is done
            (a little above the episode's 98.5 % target).
        clearance: Least distance from a viewpoint to a wall, metres.
    """

    plans_on_ground_truth = True

    def __init__(self, spacing: float = 0.5, coverage: float = 0.988,
                 clearance: float = 0.35, min_new: float = 0.05, detour: float = 2.0) -> None:
        self.spacing = spacing
        self.coverage = coverage
        self.clearance = clearance
        self.min_new = min_new
        self.detour = detour

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self.tour: list[np.ndarray] | None = None
        self.views: list[np.ndarray] = []
        self.current: np.ndarray | None = None
        self._fallback = NearestFrontier()

    @staticmethod
    def ground_truth_costmap(state: ExplorationState) -> Costmap:
        gt = state.ground_truth
        gvd = DynamicGVD(gt.shape)
        gvd.update(gt.occupied | (gt.data < 0))
        return Costmap(gt, gvd.distance2, PlannerConfig())

    def _candidates(self, state: ExplorationState) -> None:
        """Candidate viewpoints and the observable cells each one sees (once per episode)."""
        gt = state.ground_truth
        res = gt.resolution
        self.costmap = self.ground_truth_costmap(state)
        self.observable = observable_ground_truth(gt).known.reshape(-1)
        opaque = ~gt.free
        step = max(1, int(round(self.spacing / res)))
        clear = np.sqrt(self.costmap._dist2.reshape(gt.shape)) * res
        reachable = self.costmap.distances_from(state.pose[:2]) < np.inf
        cand = np.argwhere(reachable & (clear >= self.clearance))
        cand = cand[(cand[:, 0] % step == 0) & (cand[:, 1] % step == 0)]
        reach = state.sensor_range / res
        stamp = np.zeros(gt.data.size, np.int64)
        buf = np.empty(gt.data.size, np.int64)
        self.seen = []
        for i, (r, c) in enumerate(cand):
            n = _visible(opaque, r, c, reach, 360, buf, stamp, i + 1)
            cells = buf[:n]
            self.seen.append(cells[self.observable[cells]])
        self.points = gt.cell_to_world(cand)

    def _plan(self, state: ExplorationState) -> None:
        """A covering tour built greedily by new cells seen per metre of path.

        From the robot, the next viewpoint is the one with the most observable cells not
        yet known or covered, divided by (path distance + ``detour``); it repeats until the
        tour's views cover ``coverage`` of all observable cells.
        """
        covered = state.grid.data.reshape(-1) >= 0
        total = int(self.observable.sum())
        cells = self.costmap.grid.world_to_cell(self.points)
        here = np.asarray(state.pose[:2], float)
        self.tour, self.views = [], []
        while int((self.observable & covered).sum()) < self.coverage * total:
            gains = np.array([int((~covered[s]).sum()) for s in self.seen], float)
            if gains.max() <= 0:
                break
            dist = self.costmap.distances_from(here)[cells[:, 0], cells[:, 1]]
            score = np.where(np.isfinite(dist), gains / (dist + self.detour), -1.0)
            best = int(np.argmax(score))
            if score[best] <= 0:
                break
            covered[self.seen[best]] = True
            here = self.points[best]
            self.tour.append(here)
            self.views.append(self.seen[best])
        if len(self.tour) > 2:
            order = self._order(np.array(self.tour), np.asarray(state.pose[:2], float))
            self.tour = [self.tour[i] for i in order]
            self.views = [self.views[i] for i in order]

    def _order(self, points: np.ndarray, start: np.ndarray) -> list[int]:
        """Shortens the visiting order (open path from ``start``) with 2-opt on path costs."""
        nodes = np.vstack([start, points])
        cells = self.costmap.grid.world_to_cell(nodes)
        d = np.array([self.costmap.distances_from(p)[cells[:, 0], cells[:, 1]] for p in nodes])
        d = np.where(np.isfinite(d), d, 1e6)
        order = list(range(len(nodes)))
        improved = True
        while improved:
            improved = False
            for i in range(1, len(order) - 1):
                for j in range(i + 1, len(order)):
                    a, b, c = order[i - 1], order[i], order[j]
                    e = order[j + 1] if j + 1 < len(order) else None
                    before = d[a, b] + (d[c, e] if e is not None else 0.0)
                    after = d[a, c] + (d[b, e] if e is not None else 0.0)
                    if after < before - 1e-9:
                        order[i:j + 1] = order[i:j + 1][::-1]
                        improved = True
        return [k - 1 for k in order[1:]]

    def goal_open(self, grid) -> bool | None:
        """The current viewpoint is still worth reaching while enough of its view is unknown;
        None for a fallback frontier goal (the runner's frontier test applies)."""
        if self.current is None:
            return None
        if not len(self.current):
            return False
        return bool((grid.data.reshape(-1)[self.current] < 0).mean() >= self.min_new)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        if state.ground_truth is None:
            raise ValueError("the oracle needs the ground truth")
        if self.tour is None:
            self._candidates(state)
            self._plan(state)
        known = state.grid.data.reshape(-1) >= 0
        while self.tour:
            goal = self.tour.pop(0)
            view = self.views.pop(0)
            if len(view) and (~known[view]).mean() >= self.min_new and \
                    state.allowed(goal[None])[0]:
                self.current = view
                return goal
        # What the lidar did not see although the ray casting said it would (grazing
        # beams, thin gaps) is scattered: finish with the nearest frontier.
        self.current = None
        return self._fallback.select_goal(state)
