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
        self._path_cells = np.zeros(0, np.int64)
        self.status = NavStatus.IDLE
        self._last_plan = -math.inf
        self._anchor = None
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
        path = self.path
        if path is None or self.status != NavStatus.ACTIVE:
            return math.inf
        d = np.hypot(path[:, 0] - pose[0], path[:, 1] - pose[1])
        nearest = int(np.argmin(d))
        return float(d[nearest] + np.hypot(*np.diff(path[nearest:], axis=0).T).sum())

    def _replan(self, costmap: Costmap, pose: np.ndarray, t: float) -> None:
        self._last_plan = t
        path = costmap.plan(pose[:2], self.goal, goal_radius=self.config.goal_tolerance)
        if path is None:
            self.path = None
            self.status = NavStatus.NO_PATH
        else:
            self.path = path
            if self.config.replan_when_blocked:
                rc = costmap.grid.world_to_cell(path)
                self._path_cells = rc[:, 0] * costmap.grid.shape[1] + rc[:, 1]

    def lingering(self, pose: np.ndarray, t: float) -> bool:
        """True once the robot has stayed near one spot for ``linger_time`` seconds."""
        if self._anchor is None or np.hypot(*(pose[:2] - self._anchor)) > self.config.linger_radius:
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
        if np.hypot(*(pose[:2] - self.goal)) <= self.config.goal_tolerance:
            self.status = NavStatus.REACHED
            return 0.0, 0.0
        due = t - self._last_plan >= 1.0 / self.config.replan_rate_hz - 1e-9
        if not due and self.config.replan_when_blocked:
            due = bool((costmap_fn().cost[self._path_cells] < 0).any())
        if due:
            self._replan(costmap_fn(), pose, t)
            if self.status != NavStatus.ACTIVE:
                return 0.0, 0.0
        return self._pursue(pose)

    def _pursue(self, pose: np.ndarray) -> tuple[float, float]:
        path = self.path
        x, y, yaw = pose
        d = np.hypot(path[:, 0] - x, path[:, 1] - y)
        nearest = int(np.argmin(d))
        ahead = path[nearest:]
        seg = np.hypot(*np.diff(ahead, axis=0).T) if len(ahead) > 1 else np.zeros(0)
        along = np.concatenate([[0.0], np.cumsum(seg)])
        k = int(np.searchsorted(along, self.config.lookahead))
        target = ahead[min(k, len(ahead) - 1)]
        heading = math.atan2(target[1] - y, target[0] - x)
        alpha = (heading - yaw + math.pi) % (2 * math.pi) - math.pi
        p = self.profile
        if abs(alpha) > self.config.turn_in_place_angle:
            return 0.0, math.copysign(p.max_angular_speed, alpha)
        dist = max(float(np.hypot(target[0] - x, target[1] - y)), 1e-3)
        curvature = 2.0 * math.sin(alpha) / dist
        v = p.max_linear_speed * max(0.0, math.cos(alpha))
        omega = v * curvature
        if abs(omega) > p.max_angular_speed:  # Keep the curvature, slow down.
            v *= p.max_angular_speed / abs(omega)
            omega = math.copysign(p.max_angular_speed, omega)
        return v, omega
