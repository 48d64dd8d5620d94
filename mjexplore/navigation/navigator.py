"""Goal-to-motion: global path, pure-pursuit tracking, goal and lingering detection.

The stand-in for the paper's move_base: a path is planned on the known map
(:mod:`mjexplore.navigation.planner`) when the goal changes, at once when a cell of the
path stops being traversable (a newly seen wall), and otherwise at ``replan_rate_hz`` so
that newly seen shortcuts are taken (move_base plans on a new goal or a blocked path only:
its ``planner_frequency`` is 0 by default; 1 Hz gives the same exploration times as 5 Hz
on the maze and the office at half the cost of the whole loop); a pure-pursuit
controller follows it within the motion profile's limits (the simulator enforces the
acceleration limits); the goal counts as reached within ``goal_tolerance`` (the paper's
zeta = 1 m), which triggers the next decision.

Lingering (the paper's "terminated unexpectedly"): the robot staying within
``linger_radius`` of one spot for ``linger_time`` seconds of simulated time.
"""

from __future__ import annotations

import dataclasses
import enum
import math

import numba
import numpy as np

from mjexplore.navigation.planner import Costmap
from mjexplore.robot import MotionProfile


@dataclasses.dataclass(frozen=True, kw_only=True)
class NavigatorConfig:
    """Navigation settings (metres, seconds, radians).

    Attributes:
        goal_tolerance: zeta, distance at which a goal counts as reached.
        replan_rate_hz: Global replanning rate.
        lookahead: Pure-pursuit lookahead distance along the path.
        turn_in_place_angle: Heading errors above this are turned out in place.
        linger_radius: Radius of the spot the robot must leave...
        linger_time: ...within this time, or the episode ends as lingering.
        replan_when_blocked: Also replan at once when a cell of the current path stops
            being traversable (a newly seen wall); lets a low ``replan_rate_hz`` stay safe.
    """

    goal_tolerance: float = 1.0
    replan_rate_hz: float = 1.0
    lookahead: float = 0.6
    turn_in_place_angle: float = math.radians(60)
    linger_radius: float = 0.5
    linger_time: float = 60.0
    replan_when_blocked: bool = True

    def __post_init__(self) -> None:
        if min(self.goal_tolerance, self.replan_rate_hz, self.lookahead, self.linger_radius,
               self.linger_time) <= 0 or self.turn_in_place_angle < 0:
            raise ValueError("goal_tolerance, replan_rate_hz, lookahead, linger_radius and "
                             "linger_time must be > 0, turn_in_place_angle >= 0")


@numba.njit(cache=True)
def pursuit_points(xs: np.ndarray, ys: np.ndarray, segments: np.ndarray, x: float, y: float,
                   lookahead: float) -> tuple[int, float, int, float]:
    """Where a position is along a path: its nearest point, and the point pure pursuit
    steers to.

    Args:
        xs, ys: (n,) the path's points (n >= 1) in the ``map`` frame, metres.
        segments: (n - 1,) lengths of the path's segments, metres.
        x, y: The position in the ``map`` frame, metres.
        lookahead: Distance along the path, metres (> 0).

    Returns:
        The index of the point nearest (x, y) (the first of equals) and its distance from
        (x, y); the index of the first later point at least ``lookahead`` along the path
        from it (the last point if none is) and its distance from (x, y); metres.
    """
    nearest, nearest_dist = 0, math.inf
    for i in range(len(xs)):
        d = math.hypot(xs[i] - x, ys[i] - y)
        if d < nearest_dist:
            nearest, nearest_dist = i, d
    target, along = nearest, 0.0
    while target < len(xs) - 1 and along < lookahead:
        along += segments[target]
        target += 1
    return nearest, nearest_dist, target, math.hypot(xs[target] - x, ys[target] - y)


class NavStatus(enum.Enum):
    IDLE = "idle"
    ACTIVE = "active"
    REACHED = "reached"
    NO_PATH = "no_path"


class Navigator:
    """Follows a goal on the known map.

    Args:
        profile: Motion limits (speeds).
        config: Navigation settings.
    """

    def __init__(self, profile: MotionProfile, config: NavigatorConfig | None = None) -> None:
        self.profile = profile
        self.config = config or NavigatorConfig()
        self.goal: np.ndarray | None = None
        self.path: np.ndarray | None = None
        self._path_x = self._path_y = self._segments = np.zeros(0)
        self._path_cells = np.zeros(0, np.int64)
        # (costmap, version) the path was last found traversable on.
        self._checked: tuple[Costmap, int] | None = None
        self.status = NavStatus.IDLE
        self._last_plan = -math.inf
        self._anchor: np.ndarray | None = None
        self._anchor_time = 0.0

    def set_goal(self, goal: np.ndarray, costmap: Costmap, pose: np.ndarray, t: float) -> bool:
        """Starts driving to ``goal`` (x, y); returns False if no path exists."""
        self.goal = np.asarray(goal, float)
        self.status = NavStatus.ACTIVE
        self._replan(costmap, pose, t)
        return self.status == NavStatus.ACTIVE

    def remaining_length(self, pose: np.ndarray) -> float:
        """Length of the rest of the current path from ``pose``, metres (the distance to
        its nearest point, then along it); inf without a path."""
        if self.path is None or self.status != NavStatus.ACTIVE:
            return math.inf
        nearest, dist, _, _ = self._pursuit_points(pose)
        return float(dist + self._segments[nearest:].sum())

    def _pursuit_points(self, pose: np.ndarray) -> tuple[int, float, int, float]:
        """:func:`pursuit_points` of the current path from ``pose``'s (x, y)."""
        return pursuit_points(self._path_x, self._path_y, self._segments, pose[0], pose[1],
                              self.config.lookahead)

    def _replan(self, costmap: Costmap, pose: np.ndarray, t: float) -> None:
        assert self.goal is not None  # Called only while driving to a goal.
        self._last_plan = t
        path = costmap.plan(pose[:2], self.goal, goal_radius=self.config.goal_tolerance)
        if path is None:
            self.path = None
            self.status = NavStatus.NO_PATH
        else:
            self.path = path
            # Per path, not per control period: its coordinates as separate arrays and
            # the length (m) of each of its segments.
            self._path_x, self._path_y = path[:, 0].copy(), path[:, 1].copy()
            self._segments = np.hypot(*np.diff(path, axis=0).T)
            if self.config.replan_when_blocked:
                rc = costmap.grid.world_to_cell(path)
                self._path_cells = rc[:, 0] * costmap.grid.shape[1] + rc[:, 1]
                self._checked = costmap, costmap.version

    def lingering(self, pose: np.ndarray, t: float) -> bool:
        """True once the robot has stayed near one spot for ``linger_time`` seconds."""
        anchor = self._anchor
        if anchor is None or np.hypot(pose[0] - anchor[0], pose[1] - anchor[1]) > \
                self.config.linger_radius:
            self._anchor = np.array(pose[:2], float)
            self._anchor_time = t
            return False
        return t - self._anchor_time >= self.config.linger_time

    def restart_linger_clock(self, pose: np.ndarray, t: float) -> None:
        """Counts lingering afresh from ``pose`` at time ``t`` (s)."""
        self._anchor = np.array(pose[:2], float)
        self._anchor_time = t

    def update(self, pose: np.ndarray, t: float, costmap_fn) -> tuple[float, float]:
        """One control step: (v, omega) toward the goal.

        Args:
            pose: (x, y, yaw) in the ``map`` frame.
            t: Simulated time in seconds.
            costmap_fn: Builds the current :class:`Costmap` (called only to replan).
        """
        if self.status != NavStatus.ACTIVE or self.goal is None:
            return 0.0, 0.0
        goal = self.goal
        if np.hypot(pose[0] - goal[0], pose[1] - goal[1]) <= self.config.goal_tolerance:
            self.status = NavStatus.REACHED
            return 0.0, 0.0
        due = t - self._last_plan >= 1.0 / self.config.replan_rate_hz - 1e-9
        if not due and self.config.replan_when_blocked:
            costmap = costmap_fn()
            if self._checked != (costmap, costmap.version):  # Costs changed since.
                due = bool((costmap.cost[self._path_cells] < 0).any())
                self._checked = costmap, costmap.version
        if due:
            self._replan(costmap_fn(), pose, t)
            if self.status != NavStatus.ACTIVE:
                return 0.0, 0.0
        return self._pursue(pose)

    def _pursue(self, pose: np.ndarray) -> tuple[float, float]:
        x, y, yaw = pose
        _, _, k, dist = self._pursuit_points(pose)
        heading = math.atan2(self._path_y[k] - y, self._path_x[k] - x)
        alpha = (heading - yaw + math.pi) % (2 * math.pi) - math.pi
        p = self.profile
        if abs(alpha) > self.config.turn_in_place_angle:
            return 0.0, math.copysign(p.max_angular_speed, alpha)
        curvature = 2.0 * math.sin(alpha) / max(dist, 1e-3)
        v = p.max_linear_speed * max(0.0, math.cos(alpha))
        omega = v * curvature
        if abs(omega) > p.max_angular_speed:  # Keep the curvature, slow down.
            v *= p.max_angular_speed / abs(omega)
            omega = math.copysign(p.max_angular_speed, omega)
        return v, omega
