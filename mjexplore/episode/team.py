"""What only a team needs: coverage per robot, yielding, idling.

An :class:`~mjexplore.episode.engine.Episode` with N > 1 robots runs this part beside its
robots (:class:`~mjexplore.episode.agent.RobotAgent`); one robot never does. The robots
share one occupancy map, one GVD and one set of frontiers; teammates are moving bodies to
each other (:mod:`mjexplore.episode.bodies`: left out of the scans, obstacles in each
robot's costmap, waited for). Goal coordination is the explorers'
(:mod:`mjexplore.explorers.team`): they read the team at each decision in
``state.extras['team']`` (a :class:`TeamView`).

Teammates in the way. When two robots block each other (each waiting on the other, or
touching), the one with the higher index yields: it drives to the reachable place,
``yield_distance`` metres or so away, farthest from the other robot, then explores on; a
robot that stands still for good (idle, with nothing to explore, or retired) yields to any
robot it blocks.

The end of exploration holds for the team: a robot that finds no reachable frontier stands
idle and asks again every ``idle_retry`` seconds, and the episode ends (``no_frontiers``)
when every robot is idle after all have asked once more; a robot that lingers through
``linger_strikes`` goals stops for good, the others go on (``lingering`` once all have).

The team's metrics: :func:`~mjexplore.episode.metrics.team_result`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mjexplore.episode.agent import RobotAgent
from mjexplore.episode.metrics import KnownCounter
from mjexplore.mapping.map_merging import MapMergeConfig
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.mapping.scan_matching import ScanMatcherConfig
from mjexplore.maps import GridMap
from mjexplore.navigation.bodies import BodyCostmap
from mjexplore.sim.lidar import LaserScan
from mjexplore.topology.gvd import DynamicGVD


@dataclasses.dataclass(frozen=True, kw_only=True)
class TeamConfig:
    """Team settings (metres, seconds).

    Attributes:
        teammate_margin: Clearance kept from a teammate's body beyond the footprints: cells
            within its bounding circle + the planner's lethal radius + this are untraversable.
        wait_timeout: A robot waits this long for teammates or people to clear its way
            before it gives the goal up.
        retry_period: A waiting robot asks its explorer again this often.
        idle_retry: A robot with no reachable frontier asks again this often.
        yield_distance: How far a yielding robot moves out of the way (path length).
        yield_after: Two robots blocking each other this long make one yield.
        mask_teammates: Leave returns from teammates out of the map.
        unknown_starts: The robots do not know their relative start poses: each maps in its
            own frame until its map is merged into the team's
            (:mod:`mjexplore.episode.merging`).
        merge_period: An unmerged robot's map is matched against the team's this often,
            seconds of simulated time.
        merge_agreement: (metres, radians) two successive accepted matches must agree
            within for the merge to be made.
        merge: The map matcher's settings.
        merge_keep_walls: A robot placed by a merge's estimate may not turn the team's wall
            cells free (its residual error would punch holes into them).
        merge_align: After its merge, each of a robot's scans is matched against the team's
            map near where the estimate puts it (these scan matcher settings) and mapped at
            the match when it is accepted: the estimate's residual error (a fraction of a
            degree) would otherwise draw every wall a second time, a cell off, and leave
            phantom frontiers in the walls. None: map at the estimate.
    """

    teammate_margin: float = 0.1
    wait_timeout: float = 15.0
    retry_period: float = 1.0
    idle_retry: float = 5.0
    yield_distance: float = 2.0
    yield_after: float = 3.0
    mask_teammates: bool = True
    unknown_starts: bool = False
    merge_period: float = 5.0
    merge_agreement: tuple[float, float] = (0.1, math.radians(1.0))
    merge: MapMergeConfig = dataclasses.field(default_factory=MapMergeConfig)
    merge_keep_walls: bool = True
    merge_align: ScanMatcherConfig | None = dataclasses.field(
        default_factory=lambda: ScanMatcherConfig(linear_window=0.05,
                                                  angular_window=math.radians(0.5),
                                                  min_score=0.5))

    def __post_init__(self) -> None:
        if min(self.wait_timeout, self.retry_period, self.idle_retry, self.yield_distance,
               self.merge_period) <= 0 or self.teammate_margin < 0 or self.yield_after < 0 \
                or min(self.merge_agreement) < 0:
            raise ValueError("wait_timeout, retry_period, idle_retry, yield_distance and "
                             "merge_period must be > 0, teammate_margin, yield_after and "
                             "merge_agreement >= 0")


@dataclasses.dataclass
class TeamView:
    """What an explorer may know about the team at a decision (``state.extras['team']``).

    Attributes:
        index: The deciding robot.
        poses: (n, 3) every robot's (x, y, yaw), ``map`` frame.
        goals: Every robot's current goal (x, y), or None.
        costmaps: Every robot's costmap (its teammates as obstacles).
        active: Which robots still explore (not retired, not idle).
    """

    index: int
    poses: np.ndarray
    goals: list[np.ndarray | None]
    costmaps: list[BodyCostmap]
    active: np.ndarray

    @property
    def teammates(self) -> list[int]:
        return [j for j in range(len(self.poses)) if j != self.index]


class Team:
    """The team part of an episode of N > 1 robots.

    Args:
        config: Team settings.
        ground_truth: The scene's map.
        reference: Its observable part (what coverage is measured against).
        n: The number of robots.
    """

    def __init__(self, config: TeamConfig, ground_truth: GridMap, reference: GridMap,
                 n: int) -> None:
        self.config = config
        self.ground_truth = ground_truth
        # What each robot's own scans saw (coverage, overlap).
        self.own = [OccupancyMapper.like(ground_truth,
                                         MapperConfig(resolution=ground_truth.resolution))
                    for _ in range(n)]
        self.own_counters = [KnownCounter(reference) for _ in range(n)]
        self.own_curves: list[list[tuple[float, float]]] = [[] for _ in range(n)]
        self.agents: list[RobotAgent] = []  # Set by the episode once built.
        self.members = [True] * n  # Who shares the team's map (unknown starts: merged).
        self._gt_distance2: np.ndarray | None = None

    def ground_truth_distance2(self) -> np.ndarray:
        """Squared distances to the ground truth's walls and unknown cells (its GVD's), for
        the costmaps of explorers that plan on the ground truth; found once."""
        if self._gt_distance2 is None:
            gt = self.ground_truth
            gvd = DynamicGVD(gt.shape)
            gvd.update(gt.occupied | (gt.data < 0))
            self._gt_distance2 = gvd.distance2
        return self._gt_distance2

    def view(self, index: int) -> TeamView:
        """The team as robot ``index`` sees it at a decision: the robots that share its map
        (all of them, or before its merge with unknown starts itself alone)."""
        members = [a for a in self.agents if self.members[a.index]] \
            if self.members[index] else [self.agents[index]]
        return TeamView([a.index for a in members].index(index),
                        np.array([a.pose for a in members]),
                        [None if a.goal is None else a.goal.copy() for a in members],
                        [a._costmap for a in members],  # type: ignore[misc]
                        np.array([a.active for a in members]))

    def cover(self, index: int, scan: LaserScan) -> np.ndarray:
        """Maps ``scan`` into robot ``index``'s own coverage map; returns its changed cells
        (k, 2)."""
        own = self.own[index]
        changed = own.integrate(scan)
        ratio = self.own_counters[index].update(own.state, changed, own.grid.shape[1])
        self.own_curves[index].append((scan.stamp, ratio))
        return changed

    # ------------------------------------------------------------------ blocking

    def resolve_blocks(self, t: float, poses: np.ndarray) -> None:
        """Two robots that block each other (each waiting, or in contact) for
        ``yield_after`` seconds: the higher-indexed one yields (``poses``: every robot's
        true pose now)."""
        tc = self.config
        for a in self.agents:
            if not a.active or a._yield_goal is not None:
                a._blocked_since = None
                continue
            blocked = a.waiting or a.sim.in_collision and a.sim._teammate_contact
            if not blocked:
                a._blocked_since = None
                continue
            if a._blocked_since is None:
                a._blocked_since = t
            if t - a._blocked_since < tc.yield_after:
                continue
            d = np.hypot(*(poses[:, :2] - a.pose[:2]).T)
            d[a.index] = np.inf
            other = self.agents[int(np.argmin(d))]
            # A robot that stands still for good (idle or retired) moves aside for the one it
            # blocks; of two blocked robots the higher-indexed one moves aside; a robot
            # blocked by one driving on moves aside itself.
            if not other.active and other._yield_goal is None:
                if self.yield_way(other, a):
                    a._blocked_since = None
                continue
            other_blocked = other._blocked_since is not None
            if (other_blocked and a.index > other.index) or \
                    (not other_blocked and a.waiting_since is not None and
                     t - a.waiting_since >= tc.yield_after):
                if self.yield_way(a, other):
                    a._blocked_since = None

    def yield_way(self, agent: RobotAgent, other: RobotAgent) -> bool:
        """Drives ``agent`` out of ``other``'s way: to the reachable place about
        ``yield_distance`` metres off that lies farthest from it. False if none."""
        cm = agent._costmap
        dist = cm.distances_from(agent.pose[:2])
        tc = self.config
        reach = np.isfinite(dist) & (dist <= tc.yield_distance * 1.5)
        if not reach.any():
            return False
        cells = np.argwhere(reach)
        xy = agent.mapper.grid.cell_to_world(cells)
        away = np.hypot(*(xy - other.pose[:2]).T)
        d = dist[cells[:, 0], cells[:, 1]]
        score = away - 0.5 * np.abs(d - tc.yield_distance)
        return agent.drive_aside(xy[int(np.argmax(score))])

    # ------------------------------------------------------------------ results


__all__ = ["Team", "TeamConfig", "TeamView"]
