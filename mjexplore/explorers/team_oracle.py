"""The oracle extended to a team: the ground-truth coverage plan split among the robots.

The bound for a team (``--explorer oracle --robots N``). One ground-truth planner
(:class:`~mjexplore.explorers.oracle.OracleExplorer`) chooses the viewpoints that still have
to be visited (its greedy cover of the observable cells still unknown, pruned of those its
tour from the deciding robot makes redundant); :func:`split_routes` then shares them among
the exploring robots as open routes, one per robot, that keep the longest route short
(min-max): every viewpoint is inserted, farthest from the robots first, where it raises the
longest route least (ties: where it adds least), each route is re-ordered as an open tour
(OR-Tools), and viewpoints are moved off the longest route while that shortens it. A robot
drives to the first viewpoint of its route; the viewpoint a teammate is driving to stays
that teammate's (the first of its route), so that robots do not swap goals back and forth.
Path lengths are the oracle's path-graph distances on the ground truth; robots navigate on
the ground truth's costmap with their teammates' bodies in it.
"""

from __future__ import annotations

import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.explorers.oracle import OracleExplorer
from mjexplore.navigation.tour import TourConfig, open_tour

# Path lengths of places no path joins, metres: above any real route.
_NO_PATH = 1e5


def route_length(distance: np.ndarray, start: int, route: list[int]) -> float:
    """Length of the open route from place ``start`` through ``route`` (metres)."""
    places = [start, *route]
    return float(sum(distance[a, b] for a, b in zip(places, places[1:])))


def _insertion(distance: np.ndarray, start: int, route: list[int], place: int
               ) -> tuple[float, int]:
    """The least added length of inserting ``place`` into the open route, and where (its
    index in ``route``; ``len(route)``: at the end)."""
    places = np.array([start, *route])
    added = np.append(distance[places[:-1], place] + distance[place, places[1:]]
                      - distance[places[:-1], places[1:]], distance[places[-1], place])
    k = int(np.argmin(added))
    return float(added[k]), k


def split_routes(distance: np.ndarray, robots: int, pinned: dict[int, int] | None = None,
                 tour: TourConfig | None = None, moves: int = 50) -> list[list[int]]:
    """Open routes for ``robots`` robots over the other places, keeping the longest short.

    Args:
        distance: (r + m, r + m) path lengths in metres (inf: no path); places 0..r-1 are
            the robots' positions, r.. the viewpoints.
        robots: r.
        pinned: Robot -> viewpoint place that stays first on its route.
        tour: Settings of the open-tour solver that re-orders each route.
        moves: Most single-viewpoint moves off the longest route.

    Returns:
        Each robot's viewpoint places in visiting order (every viewpoint on one route).
    """
    d = np.where(np.isfinite(distance), distance, _NO_PATH)
    pinned = pinned or {}
    routes = [[pinned[k]] if k in pinned else [] for k in range(robots)]
    free = [p for p in range(robots, len(d)) if p not in pinned.values()]
    # Farthest from every robot first (those shape the routes), as farthest insertion.
    free.sort(key=lambda p: -d[:robots, p].min())
    lengths = [route_length(d, k, r) for k, r in enumerate(routes)]

    def insertion(k: int, p: int) -> tuple[float, int]:
        if k in pinned:  # After the pinned viewpoint.
            added, at = _insertion(d, routes[k][0], routes[k][1:], p)
            return added, at + 1
        return _insertion(d, k, routes[k], p)

    for p in free:
        best: tuple[tuple[float, float], int, int] | None = None
        for k in range(robots):
            added, at = insertion(k, p)
            worst = max(max(lengths[:k] + lengths[k + 1:], default=0.0), lengths[k] + added)
            if best is None or (worst, added) < best[0]:
                best = (worst, added), k, at
        assert best is not None  # Some robot's route takes it (robots >= 1).
        _, k, at = best
        routes[k].insert(at, p)
        lengths[k] = route_length(d, k, routes[k])

    def reorder(k: int) -> None:
        head = routes[k][:1] if k in pinned else []
        rest = routes[k][len(head):]
        if len(rest) > 1:
            start = head[0] if head else k
            places = [start, *rest]
            order = open_tour(d[np.ix_(places, places)], tour)
            routes[k] = head + [places[j] for j in order]
        lengths[k] = route_length(d, k, routes[k])

    for k in range(robots):
        reorder(k)
    for _ in range(moves):
        worst = int(np.argmax(lengths))
        movable = routes[worst][1:] if worst in pinned else routes[worst]
        move: tuple[float, int, int, int] | None = None
        for p in movable:
            rest = [q for q in routes[worst] if q != p]
            left = route_length(d, worst, rest)
            for k in range(robots):
                if k == worst:
                    continue
                added, at = insertion(k, p)
                new_worst = max(left, lengths[k] + added,
                                *(lengths[j] for j in range(robots) if j not in (k, worst)))
                if new_worst < lengths[worst] - 1e-6 and (move is None or new_worst < move[0]):
                    move = new_worst, p, k, at
        if move is None:
            break
        _, p, k, at = move
        routes[worst].remove(p)
        routes[k].insert(at, p)
        reorder(worst)
        reorder(k)
    return routes


class TeamOracle:
    """The coordinator of an oracle team (see the module docstring).

    Args:
        n: Robots in the team.
        replan_period: Each robot asks for its route again this often, seconds (None: when
            it reaches its viewpoint, or the viewpoint is seen, as the oracle).
        **kwargs: :class:`OracleExplorer`'s settings.
    """

    def __init__(self, n: int, replan_period: float | None = None, **kwargs) -> None:
        self.planner = OracleExplorer(**kwargs)
        self.replan_period = replan_period
        self.members = [OracleMember(self, i) for i in range(n)]
        self.splits = 0

    def reset(self, rng: np.random.Generator) -> None:
        self.planner.reset(rng)

    def goal_for(self, member: OracleMember, state: ExplorationState) -> np.ndarray | None:
        """The deciding robot's next viewpoint: the first of its share of the plan."""
        planner = self.planner
        plan = planner.replan(state)
        team = state.extras.get("team")
        if not plan:
            return None
        assert planner.views is not None and planner.graph is not None  # Set by replan.
        if team is None:
            member.current = plan[0]
            return planner.views.points[plan[0]].copy()
        me = team.index
        robots = [k for k in range(len(team.poses)) if k == me or team.active[k]]
        points = np.vstack([team.poses[robots, :2], planner.views.points[plan]])
        distance = planner.graph.distance_matrix(points)
        r = len(robots)
        pinned = {}
        for row, k in enumerate(robots):
            goal = team.goals[k]
            if k != me and goal is not None:
                near = np.flatnonzero(np.hypot(*(planner.views.points[plan] - goal).T) < 1e-6)
                if len(near):
                    pinned[row] = r + int(near[0])
        routes = split_routes(distance, r, pinned, planner.tour_config)
        self.splits += 1
        mine = routes[robots.index(me)]
        if not mine:
            return None  # More robots than viewpoints: the nearest frontier instead.
        member.current = plan[mine[0] - r]
        return planner.views.points[member.current].copy()


class OracleMember:
    """One robot's explorer in an oracle team: asks the shared coordinator."""

    name = "oracle"
    plans_on_ground_truth = True

    def __init__(self, coordinator: TeamOracle, index: int) -> None:
        self.coordinator = coordinator
        self.index = index
        self.replan_period = coordinator.replan_period
        self.current: int | None = None

    def reset(self, rng: np.random.Generator) -> None:
        self.current = None
        if self.index == 0:
            self.coordinator.reset(rng)

    def goal_open(self, grid) -> bool | None:
        """As the oracle's: the robot's viewpoint stays worth reaching while it still sees
        ``min_gain`` observable cells unknown in ``grid``."""
        planner = self.coordinator.planner
        planner.current = self.current
        return planner.goal_open(grid)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        goal = self.coordinator.goal_for(self, state)
        if goal is None:
            self.current = None
        return goal


__all__ = ["OracleMember", "TeamOracle", "route_length", "split_routes"]
