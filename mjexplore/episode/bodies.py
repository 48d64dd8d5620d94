"""Moving bodies around the robots: their teammates and the people they see.

Walls stay; bodies move. An :class:`~mjexplore.episode.engine.Episode` with teammates (N > 1
robots) or people (a world with a crowd, :mod:`mjexplore.sim.people`) runs this part; a
robot alone in a static building never does.

* **Scans.** A robot's lidar returns from a moving body are left out of what it maps, so
  that bodies neither leave trails of phantom walls in the map nor stand in it as walls
  that hide frontiers: a teammate's returns are found from the pose the team shares; a
  person's by a person detector on the scan, here a perfect one: the returns within the
  person's disc plus :data:`RETURN_MARGIN` of its true centre are that person's, as a leg
  tracker would segment them. The beams stay unmapped (NaN), the space in front of the
  body is cleared by the beams around it and by later scans.
* **Costmaps.** Each robot plans on a :class:`~mjexplore.navigation.bodies.BodyCostmap` in
  which the bodies it knows are obstacles, set anew every control period: its teammates
  where they stand, and the people its last scan saw where they stand now (a tracker that
  keeps each person's identity between scans).
* **Waiting.** A robot whose goal no path reaches while one would without the bodies waits
  for them to move on, asking its explorer again every ``retry_period`` seconds, and gives
  the goal up only after ``wait_timeout`` seconds
  (:meth:`~mjexplore.episode.agent.RobotAgent.give_up`; :class:`~mjexplore.episode.team.
  TeamConfig` holds both, for teams and for a robot alone among people).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from mjexplore.navigation.bodies import BodyCostmap
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.motion import BODY_RADIUS

if TYPE_CHECKING:
    from mjexplore.episode.agent import RobotAgent

# Returns within a body's radius plus this of its true centre are the body's, metres.
RETURN_MARGIN = 0.1


def returns_near(scan: LaserScan, centres: np.ndarray, reach: float) -> np.ndarray:
    """(k, beams) bool: which of ``scan``'s finite returns end within ``reach`` metres of
    each of the ``centres`` ((k, 2), ``map`` frame)."""
    ranges = scan.ranges
    finite = np.isfinite(ranges)
    x, y, yaw = scan.pose
    a = scan.angles + yaw
    r = np.where(finite, ranges, 0.0)
    ex, ey = x + r * np.cos(a), y + r * np.sin(a)
    centres = np.asarray(centres, float).reshape(-1, 2)
    near = np.hypot(ex[None] - centres[:, :1], ey[None] - centres[:, 1:]) < reach
    return near & finite[None]


class MovingBodies:
    """The moving-bodies part of an episode (module docstring).

    Args:
        agents: The episode's robots.
        crowd: The world's people (:class:`~mjexplore.sim.people.Crowd`), or None.
        mask_teammates: Leave teammates' returns out of the map.
    """

    def __init__(self, agents: list[RobotAgent], crowd: Any,
                 mask_teammates: bool = True) -> None:
        self.agents = agents
        self.crowd = crowd
        self.mask_teammates = mask_teammates
        # The people each robot's last scan saw (indices into the crowd).
        self.seen = [np.zeros(0, np.int64) for _ in agents]
        self.masked_returns = 0  # Teammates' returns left out.
        self.people_returns = 0  # People's returns left out.

    def mask(self, index: int, scan: LaserScan, centres: np.ndarray) -> LaserScan:
        """Robot ``index``'s scan with the returns from its teammates (``centres``: every
        robot's true body centre now, (n, 2)) and from people made invalid (NaN); notes the
        people it saw."""
        hit = np.zeros(len(scan.ranges), bool)
        others = np.delete(centres, index, axis=0)
        if len(others) and self.mask_teammates:
            teammates = returns_near(scan, others, BODY_RADIUS + RETURN_MARGIN).any(axis=0)
            self.masked_returns += int(teammates.sum())
            hit |= teammates
        if self.crowd is not None and len(self.crowd):
            people = returns_near(scan, self.crowd.positions,
                                  self.crowd.config.radius + RETURN_MARGIN)
            self.seen[index] = np.flatnonzero(people.any(axis=1))
            people = people.any(axis=0) & ~hit
            self.people_returns += int(people.sum())
            hit |= people
        if not hit.any():
            return scan
        masked = scan.ranges.copy()
        masked[hit] = np.nan
        return dataclasses.replace(scan, ranges=masked)

    def set_costmaps(self, centres: np.ndarray) -> None:
        """Puts into each robot's costmap its teammates (their body centres now, (n, 2))
        and the people its last scan saw, where they stand now."""
        for a in self.agents:
            costmap = a._costmap
            assert isinstance(costmap, BodyCostmap)  # Every robot among bodies plans on one.
            people = None
            if self.crowd is not None and len(self.seen[a.index]):
                people = self.crowd.positions[self.seen[a.index]]
            costmap.set_bodies(np.delete(centres, a.index, axis=0), people)


__all__ = ["RETURN_MARGIN", "MovingBodies", "returns_near"]
