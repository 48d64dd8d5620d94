"""Coordination for teams of robots exploring one shared map.

A team's explorers are one per robot (the team engine,
:class:`~mjexplore.episode.engine.Episode` of a team, asks each robot's own); coordinated ones read
the team (``state.extras['team']``, a :class:`~mjexplore.episode.team.TeamView`: every
robot's pose, goal and costmap) and may share a coordinator. The baselines:

* the **naive team**: each robot runs a single-robot explorer on the shared map, unaware
  of the others except as obstacles (any single-robot method; built by the caller);
* **frontier assignment by path cost** (``assign_greedy``, ``assign_optimal``): the
  frontiers are grouped into regions (frontiers within ``region_radius`` of a region's
  first one; one robot per region, so that two robots do not head for the same room), every
  exploring robot's path cost to every region is computed on its own costmap, and robots
  are assigned to regions one each: greedily, the cheapest robot-region pair first
  (Burgard et al.'s coordinated exploration with path costs), or optimally, the assignment
  of least total cost (the Hungarian method, ``scipy.optimize.linear_sum_assignment``). A
  robot goes to the cheapest frontier of its region. Robots with no region left (more
  robots than regions) take their cheapest region. A robot's current goal's region costs
  ``hysteresis`` metres less, so that assignments do not flip between equal choices; each
  robot re-asks every ``replan_period`` seconds, so new assignments take hold;
* **MMPF's multi-robot potential field** (``mmpf``): the single-robot field
  (:class:`~mjexplore.explorers.potential.PotentialField`) plus the robot-robot repulsion of
  Yu et al.'s MMPF (ICRA 2021; as Explore-Bench's ``mmpf_node`` has it): each teammate
  within ``interfere_radius`` (Manhattan distance) raises the potential by its nearness;
* the **team oracle** (``oracle``, the bound): the ground-truth oracle's viewpoints split
  among the robots into routes that keep the longest short
  (:mod:`mjexplore.explorers.team_oracle`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import linear_sum_assignment

from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.errors import UserInputError
from mjexplore.explorers.potential import PotentialField
from mjexplore.explorers.team_oracle import TeamOracle

TEAM_METHODS: dict[str, str] = {
    "assign_greedy": "frontier regions assigned greedily by path cost (cheapest pair first)",
    "assign_optimal": "frontier regions assigned by least total path cost (Hungarian method)",
    "mmpf": "MMPF's multi-robot potential field with robot-robot repulsion",
    "oracle": "the ground-truth oracle's viewpoints split into min-max routes (the bound)",
}
# Path costs of regions a robot cannot reach, metres: above any real one.
UNREACHABLE = 1e6


def frontier_regions(points: np.ndarray, radius: float) -> np.ndarray:
    """Region label of each of the (n, 2) frontier goals: in order, a frontier joins the
    first region whose first frontier lies within ``radius`` metres, else starts one."""
    labels = np.full(len(points), -1, np.int64)
    seeds: list[int] = []
    for i, p in enumerate(points):
        for k, s in enumerate(seeds):
            if np.hypot(*(p - points[s])) <= radius:
                labels[i] = k
                break
        else:
            labels[i] = len(seeds)
            seeds.append(i)
    return labels


def assign(cost: np.ndarray, method: str) -> np.ndarray:
    """Column (region) assigned to each row (robot) of ``cost`` (rows x columns, metres;
    ``UNREACHABLE`` where there is no path), -1 where none is: ``greedy`` takes the
    cheapest reachable pair first, ``optimal`` the least total cost (Hungarian method)."""
    rows, cols = cost.shape
    out = np.full(rows, -1, np.int64)
    if method == "optimal":
        r, c = linear_sum_assignment(cost)
        keep = cost[r, c] < UNREACHABLE
        out[r[keep]] = c[keep]
        return out
    if method != "greedy":
        raise ValueError(f"unknown assignment method {method!r}")
    free_rows, free_cols = np.ones(rows, bool), np.ones(cols, bool)
    masked = cost.astype(float).copy()
    for _ in range(min(rows, cols)):
        k = int(np.argmin(masked))
        r, c = divmod(k, cols)
        if masked[r, c] >= UNREACHABLE:
            break
        out[r] = c
        free_rows[r] = free_cols[c] = False
        masked[r, :] = np.inf
        masked[:, c] = np.inf
    return out


class FrontierAssignment:
    """The coordinator of an assignment team (see the module docstring).

    Args:
        n: Robots in the team.
        method: 'greedy' or 'optimal'.
        region_radius: Frontiers within this distance (metres) of a region's first
            frontier form one region.
        hysteresis: A robot's cost to the region of its current goal is this much lower,
            metres.
        replan_period: Each robot asks for its assignment again this often, seconds.
    """

    def __init__(self, n: int, method: str = "greedy", region_radius: float = 3.0,
                 hysteresis: float = 2.0, replan_period: float = 5.0) -> None:
        if method not in ("greedy", "optimal"):
            raise UserInputError(f"assignment method {method!r} is unknown: use greedy or "
                                 "optimal.")
        self.n = n
        self.method = method
        self.region_radius = region_radius
        self.hysteresis = hysteresis
        self.replan_period = replan_period
        self.members = [AssignedFrontier(self, i) for i in range(n)]
        self.assignments = 0

    def goal_for(self, state: ExplorationState) -> np.ndarray | None:
        """The deciding robot's goal: the cheapest frontier of its assigned region."""
        team = state.extras.get("team")
        if team is None or not state.frontiers:
            return NearestFrontier().select_goal(state)
        me = team.index
        points = np.array([f.goal for f in state.frontiers])
        labels = frontier_regions(points, self.region_radius)
        robots = [k for k in range(len(team.poses)) if k == me or team.active[k]]
        dist = np.full((len(robots), len(points)), np.inf)
        for row, k in enumerate(robots):
            view = dataclasses.replace(state, pose=team.poses[k], costmap=team.costmaps[k])
            dist[row] = view.frontier_distances()
        regions = labels.max() + 1
        cost = np.full((len(robots), regions), np.inf)
        for g in range(regions):
            cost[:, g] = dist[:, labels == g].min(axis=1)
        for row, k in enumerate(robots):
            goal = team.goals[k]
            if goal is not None:
                near = np.hypot(*(points - goal).T) <= 0.5
                for g in np.unique(labels[near]):
                    cost[row, g] -= self.hysteresis
        cost = np.where(np.isfinite(cost), np.maximum(cost, 0.0), UNREACHABLE)
        mine = robots.index(me)
        if not np.isfinite(dist[mine]).any():
            return None
        self.assignments += 1
        region = assign(cost, self.method)[mine]
        if region < 0:  # More robots than regions: the cheapest one.
            region = int(np.argmin(cost[mine]))
        members = np.flatnonzero(labels == region)
        return points[members[np.argmin(dist[mine, members])]]


class AssignedFrontier:
    """One robot's explorer in an assignment team: asks the shared coordinator."""

    def __init__(self, coordinator: FrontierAssignment, index: int) -> None:
        self.coordinator = coordinator
        self.index = index
        self.name = f"assign_{coordinator.method}"
        self.replan_period = coordinator.replan_period

    def reset(self, rng: np.random.Generator) -> None:
        del rng

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        return self.coordinator.goal_for(state)


class TeamPotentialField(PotentialField):
    """MMPF's multi-robot field: the single robot's, plus each teammate's repulsion.

    Args:
        interfere_radius: Teammates within this Manhattan distance (metres) of a cell repel
            it (MMPF's ``ROBOT_INTERFERE_RADIUS``: 50 cells of 0.05 m).
        repulsion: Potential per metre of nearness within ``interfere_radius``, in units of
            the attraction's (frontier cells per coarse cell of wavefront distance). The
            default keeps MMPF's ratio of repulsion to attraction: its repulsion counts
            map cells (0.05 m) of nearness against attraction per map cell of distance,
            ours measures distance in coarse cells (4 map cells), so 4 x 20 per metre.
        **kwargs: :class:`PotentialField`'s settings.
    """

    name = "mmpf"

    def __init__(self, interfere_radius: float = 2.5, repulsion: float = 80.0,
                 **kwargs) -> None:
        super().__init__(**kwargs)
        self.interfere_radius = interfere_radius
        self.repulsion = repulsion

    def add_potential(self, state: ExplorationState, potential: np.ndarray, f: int) -> None:
        team = state.extras.get("team")
        if team is None:
            return
        grid = state.grid
        rows, cols = potential.shape
        cell = grid.resolution * f
        y = grid.origin[1] + (np.arange(rows) + 0.5) * cell
        x = grid.origin[0] + (np.arange(cols) + 0.5) * cell
        for k in team.teammates:
            px, py = team.poses[k][:2]
            d = np.abs(y - py)[:, None] + np.abs(x - px)[None, :]
            potential += self.repulsion * np.maximum(self.interfere_radius - d, 0.0)


def make_team_explorers(method: str, n: int, **kwargs) -> list[Explorer]:
    """The ``n`` explorers of a coordinated team method (:data:`TEAM_METHODS`).

    Raises:
        UserInputError: not a team method (a single-robot method runs as the naive team,
            built by the caller).
    """
    if method in ("assign_greedy", "assign_optimal"):
        return list(FrontierAssignment(n, method.split("_")[1], **kwargs).members)
    if method == "mmpf":
        return [TeamPotentialField(**kwargs) for _ in range(n)]
    if method == "oracle":
        return list(TeamOracle(n, **kwargs).members)
    raise UserInputError(f"unknown team method {method!r}: use one of "
                         f"{', '.join(TEAM_METHODS)}, or a single-robot method for the naive "
                         "team.")


__all__ = ["TEAM_METHODS", "AssignedFrontier", "FrontierAssignment", "TeamPotentialField",
           "assign", "frontier_regions", "make_team_explorers"]
