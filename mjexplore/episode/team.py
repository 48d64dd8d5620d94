"""A team exploration episode: N robots, one shared map, one navigator each.

The robots start at known poses in one frame (the ``map`` frame), so every robot's scans go
into one occupancy map, one GVD and one set of frontiers from the first scan on. Each robot
is a :class:`RobotAgent`: the single-robot engine's decision and navigation machinery
(:class:`~mjexplore.episode.engine.Episode`'s goal adoption, progress clock, blacklist,
fallback, lingering and stuck recovery) bound to its robot of the team's world (MuJoCo's
:class:`~mjexplore.sim.team.TeamSimulator`, physics or kinematic, or the grid world's
:class:`~mjexplore.sim.team_grid.TeamGridWorld`), to the shared map, and to a costmap of its own
in which its teammates' bodies are obstacles (:class:`~mjexplore.navigation.teammates.
TeamCostmap`, set anew every control period).

Teammates in the way. A robot whose goal no path reaches while one would without the
teammates *waits*: it stands, asks its explorer again every ``retry_period`` seconds (it
may choose another goal), and gives the goal up (as unreachable, to be offered again later)
only after ``wait_timeout`` seconds. When two robots block each other (each waiting on
the other, or touching), the one with the higher index yields: it drives to the reachable
place, ``yield_distance`` metres or so away, farthest from the other robot, then explores
on; a robot that stands still for good (idle, with nothing to explore, or retired) yields to
any robot it blocks. Returns of the lidar that come from teammates (their known poses) are
not mapped, so robots do not leave trails of phantom walls in the shared map.

The end of exploration holds for the team: the episode ends when the team's map reaches
the target ratio (``explored``); when no robot finds a reachable frontier (``no_frontiers``:
a robot that finds none stands idle and asks again every ``idle_retry`` seconds, and when
every robot is idle they all ask once more before the episode ends); when every robot has
been retired for lingering (``lingering``: a robot that lingers through ``linger_strikes``
goals stops, the others go on); when a robot tips over or the physics fails; at the time
cap. Only ground-truth localisation is supported (each robot knows its pose in its own frame).

Unknown start poses (``TeamConfig.unknown_starts``): the robots do not know where they
started relative to each other. Each robot maps in a frame of its own (its start pose is the
frame's origin) and explores alone on its own map, its explorer seeing a team of one, until
its map overlaps the team's enough to be merged by matching
(:func:`~mjexplore.mapping.map_merging.merge_maps`: robot ``j``'s own-frame map, grown from
its scans at its poses relative to its start, placed in the team's map). The team's map is
robot 0's: its frame is robot 0's start, drawn in the ground truth's grid at robot 0's true
start pose (a fixed change of coordinates, as an evaluator aligns a robot's map to the
ground truth; it tells the robots nothing). Likewise, before its merge a robot's own map is
drawn in the ground truth's grid through its own start pose, so that the mapping and
planning machinery is the shared map's. A match counts once a second one, ``merge_period``
seconds later, agrees with it (within ``merge_agreement``); then the robot's scans so far
are mapped into the team's map at the poses the estimate of its start gives, the robot
plans on the team's map from then on, its pose in it being its own-frame pose composed
with the estimate, and the team's coordination takes it in. Each later scan of the robot
is aligned to the team's map by a scan match before it is mapped (``merge_align``), and
may not turn the team's wall cells free (``merge_keep_walls``): the estimate's residual
error, a few hundredths of a degree, would otherwise draw the walls a second time a cell
off and punch holes into them, phantom frontiers (on the office, enough to double the
team's time). The merge's error is the estimated start pose against the true one (metres
and degrees, in ``merges`` of the metrics). The team's exploration ratio is that of the
union of the robots' maps until all
have merged, then that of the team's map. Robots see each other before they merge (their
lidars do), so their bodies are obstacles in each other's costmaps throughout.

Metrics: the team's exploration ratio and times to 80, 90 and 98.5 %, IoU, the robots'
summed and longest path, wall collisions, robot-robot collisions (per pair and contact),
Explore-Bench's overlap ratio (the robots' own explored areas summed over the team's, less
one: 0 when no cell was seen by two robots, 1 when each saw everything), and per robot its
path, coverage (what its own scans saw), collisions, decisions and waits.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mjexplore.episode.engine import (
    Episode,
    EpisodeConfig,
    Interrupted,
    SigintFlag,
)
from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.episode.metrics import KnownCounter, first_time_at
from mjexplore.errors import UserInputError
from mjexplore.mapping.map_merging import MapMergeConfig, merge_maps
from mjexplore.mapping.metrics import iou, observable_ground_truth
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.mapping.scan_matching import ScanMatcherConfig, match_scan, scan_points
from mjexplore.maps import OCCUPIED, GridMap
from mjexplore.navigation.navigator import Navigator, NavStatus
from mjexplore.navigation.teammates import TeamCostmap
from mjexplore.scenes.scene import SceneFiles
from mjexplore.scenes.team import check_starts, draw_starts
from mjexplore.sim.kinematics import KinematicsLog
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.motion import BODY_RADIUS
from mjexplore.sim.odometry import compose_pose, relative_pose, wrap_angle
from mjexplore.sim.team import TeamRobot
from mjexplore.sim.team_grid import TeamGridRobot, make_team_world
from mjexplore.topology.gvd import DynamicGVD
from mjexplore.topology.pipeline import TopologyTracker

TEAM_END_REASONS = ("explored", "no_frontiers", "lingering", "tipped_over", "time_limit",
                    "physics_fault", "interrupted")
# Exploration ratios whose first times the team's metrics report.
TEAM_MILESTONES = ((0.80, "t80_s"), (0.90, "t90_s"), (0.985, "t985_s"))


@dataclasses.dataclass(frozen=True, kw_only=True)
class TeamConfig:
    """Team settings (metres, seconds).

    Attributes:
        teammate_margin: Clearance kept from a teammate's body beyond the footprints: cells
            within its bounding circle + the planner's lethal radius + this are untraversable.
        wait_timeout: A robot waits this long for teammates to clear its way before it
            gives the goal up.
        retry_period: A waiting robot asks its explorer again this often.
        idle_retry: A robot with no reachable frontier asks again this often.
        yield_distance: How far a yielding robot moves out of the way (path length).
        yield_after: Two robots blocking each other this long make one yield.
        mask_teammates: Leave returns from teammates out of the map.
        unknown_starts: The robots do not know their relative start poses: each maps in its
            own frame until its map is merged into the team's (see the module docstring).
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
    costmaps: list[TeamCostmap]
    active: np.ndarray

    @property
    def teammates(self) -> list[int]:
        return [j for j in range(len(self.poses)) if j != self.index]


@dataclasses.dataclass
class TeamEpisodeResult:
    """What a team episode produced.

    Attributes:
        metrics: The team's metrics, with ``per_robot`` (a list of dicts).
        ratio_curve: (n, 2) time (s) and the team's exploration ratio after each scan.
        robot_curves: Each robot's (m, 2) time and own coverage ratio.
        kinematics: Each robot's kinematics log.
        grid: The final shared map.
        goals: Each robot's (m, 3) decision time and goal.
        starts: The robots' start poses.
    """

    metrics: dict[str, Any]
    ratio_curve: np.ndarray
    robot_curves: list[np.ndarray]
    kinematics: list[KinematicsLog]
    grid: GridMap
    goals: list[np.ndarray]
    starts: list[tuple[float, float, float]]


class RobotAgent(Episode):
    """One robot of a team: the single-robot engine's decisions and navigation, bound to
    its :class:`TeamRobot`, the team's shared map and its own :class:`TeamCostmap`.

    Not built by :meth:`Episode.__init__` (the team owns the world and the map); the
    attributes the engine's methods read are set here.
    """

    sim: TeamRobot | TeamGridRobot

    def __init__(self, team: TeamEpisode, index: int, robot: TeamRobot | TeamGridRobot,
                 explorer: Explorer, rng: np.random.Generator) -> None:  # noqa: D107
        cfg = team.config
        self.team = team
        self.index = index
        self.config = cfg
        self.scene = team.scene
        self.explorer = explorer
        self.observer = None
        self.sim = robot
        self.localizer = None
        self._positions: list[tuple[float, float, float, float]] = []
        self.reference = team.reference
        self.navigator = Navigator(robot.profile, cfg.navigator)
        self.use_map(*team.map_of(index))
        self._static_costmap = None
        explorer.reset(rng)
        self._start_deciding()
        self.curve = team.curve
        self.goals: list[tuple[float, float, float]] = []
        self.visited: list[np.ndarray] = []
        self.end_reason: str | None = None
        # Team state.
        self.retired: str | None = None  # Why the robot stopped for good ('lingering').
        self.idle_until: float | None = None  # Next retry, while it finds nothing to do.
        self.idle_since = 0.0
        self.idle_time = 0.0
        self.waiting_since: float | None = None  # Set while teammates block its goal.
        self._retry_at = 0.0
        self.waits = 0
        self.wait_time = 0.0
        self.yields = 0
        self._yield_goal: np.ndarray | None = None
        self._blocked_since: float | None = None

    def use_map(self, mapper: OccupancyMapper, tracker: TopologyTracker,
                counter: KnownCounter) -> None:
        """Plans on ``mapper``'s map (with ``tracker``'s GVD and frontiers) from now on."""
        self.mapper = self._seen = mapper
        self.tracker = tracker
        self.counter = counter
        radius = BODY_RADIUS + self.config.planner.lethal_radius + \
            self.team.team_config.teammate_margin
        if getattr(self.explorer, "plans_on_ground_truth", False):
            # An explorer that knows the ground truth (the team oracle) also navigates on it.
            gt = self.scene.ground_truth
            assert gt is not None  # TeamEpisode checked the scene.
            self._costmap: TeamCostmap = TeamCostmap(
                gt, self.team.ground_truth_distance2(),
                self.config.planner, radius)
        else:
            self._costmap = TeamCostmap(mapper.grid, tracker.gvd.distance2,
                                        self.config.planner, radius)

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of ``base_link`` in the frame of the map the robot plans on: the true
        pose, or once merged with unknown starts, its own-frame pose placed by the merge's
        estimate of its start."""
        correction = self.team.corrections[self.index]
        pose = self.sim.pose
        return pose if correction is None else compose_pose(correction, pose)

    # ------------------------------------------------------------------ engine hooks

    def decision_state(self) -> ExplorationState:
        state = super().decision_state()
        state.extras["team"] = self.team.view(self.index)
        return state

    def _give_up(self, reason: str) -> None:
        """As the engine's, except that a goal only the teammates keep out of reach is
        waited for (``wait_timeout``) before it is given up."""
        assert self.goal is not None  # Given up only once adopted.
        t = self.sim.time
        tc = self.team.team_config
        if reason == "no_path" and self._yield_goal is None and \
                self._costmap.blocked_by_teammates(self.pose[:2], self.goal,
                                                   self.config.navigator.goal_tolerance):
            if self.waiting_since is None:
                self.waiting_since = t
                self.waits += 1
            if t - self.waiting_since < tc.wait_timeout:
                self.navigator.status = NavStatus.NO_PATH
                self._decision_due = True
                self._retry_at = t + tc.retry_period
                return
        self._end_wait(t)
        super()._give_up(reason)

    def _end_wait(self, t: float) -> None:
        if self.waiting_since is not None:
            self.wait_time += t - self.waiting_since
            self.waiting_since = None

    def _decide(self) -> bool:
        """The engine's decision, except that a waiting robot asks again only every
        ``retry_period`` and stops asking once it waits."""
        t = self.sim.time
        if self.waiting_since is not None and t < self._retry_at:
            return True
        for _ in range(8):
            state = self.decision_state()
            goal = self.explorer.select_goal(state)
            if goal is None:
                return self.decide_fallback()
            if self.adopt_goal(goal, state):
                self._end_wait(t)
                return True
            if self.waiting_since is not None:
                return True
        return True

    @property
    def waiting(self) -> bool:
        return self.waiting_since is not None

    @property
    def active(self) -> bool:
        return self.retired is None and self.idle_until is None

    # ------------------------------------------------------------------ yielding

    def yield_way(self, other: RobotAgent) -> bool:
        """Drives out of ``other``'s way: to the reachable place about
        ``yield_distance`` metres off that lies farthest from it. False if none."""
        cm = self._costmap
        dist = cm.distances_from(self.pose[:2])
        tc = self.team.team_config
        reach = np.isfinite(dist) & (dist <= tc.yield_distance * 1.5)
        if not reach.any():
            return False
        cells = np.argwhere(reach)
        xy = self.mapper.grid.cell_to_world(cells)
        away = np.hypot(*(xy - other.pose[:2]).T)
        d = dist[cells[:, 0], cells[:, 1]]
        score = away - 0.5 * np.abs(d - tc.yield_distance)
        target = xy[int(np.argmax(score))]
        self._end_wait(self.sim.time)
        if not self.navigator.set_goal(target, cm, self.pose, self.sim.time):
            return False
        self.goal = target
        self._yield_goal = target
        self.goals.append((self.sim.time, *target))
        self.yields += 1
        self._best_distance = self.navigator.remaining_length(self.pose)
        self._best_time = self._decided_at = self.sim.time
        self._decision_due = False
        return True

    def decision_due(self) -> bool:
        if self._yield_goal is not None:
            t = self.sim.time
            if self.navigator.status == NavStatus.ACTIVE and \
                    t - self._best_time <= self.config.progress_timeout:
                d = self.navigator.remaining_length(self.pose)
                if d < self._best_distance - 0.25:
                    self._best_distance, self._best_time = d, t
                return False
            self._yield_goal = None  # Moved aside (or could not): explore on.
            self.goal = None
            self._decision_due = True
            return True
        return super().decision_due()


class TeamEpisode:
    """Runs one team episode.

    Args:
        scene: The scene (with its ground-truth map).
        explorers: One explorer per robot (a coordinated team's share a coordinator).
        seed: Seed for the start poses, sensor noise and explorers.
        config: Episode settings, as a single robot's (``localization`` must be
            'ground_truth'; ``sim.dynamics`` any world's: physics, kinematic or grid).
        starts: One start pose per robot; None: robot 0 where a single robot's episode of
            this seed starts, the others drawn around it
            (:func:`~mjexplore.scenes.team.draw_starts`).
        team_config: Team settings.
        observer: Optional object with any of the hooks ``on_scan(episode, index, scan)``,
            ``on_goal(episode, index, t, x, y)`` (a robot's new goal) and
            ``on_step(episode)``.
    """

    def __init__(self, scene: SceneFiles, explorers: Sequence[Explorer], seed: int,
                 config: EpisodeConfig | None = None, starts: list | None = None,
                 team_config: TeamConfig | None = None, observer: Any = None) -> None:
        if scene.ground_truth is None:
            raise ValueError("episodes need a scene with a ground-truth map")
        self.config = config or EpisodeConfig()
        self.team_config = team_config or TeamConfig()
        cfg = self.config
        if cfg.localization != "ground_truth":
            raise UserInputError("a team explores with known start poses in one frame: use "
                                 "localization ground_truth.")
        if not explorers:
            raise UserInputError("a team needs at least one robot.")
        self.scene = scene
        self.observer = observer
        gt = scene.ground_truth
        n = len(explorers)
        rng = np.random.default_rng(seed)
        if starts is None:
            first = Episode._jittered_start(self, scene, gt, rng)
            starts = draw_starts(gt, first, n, np.random.default_rng([seed, n]))
        elif len(starts) != n:
            raise UserInputError(f"{len(starts)} start poses for {n} robots: give one per "
                                 "robot.")
        starts = [tuple(float(v) for v in p) for p in starts]
        check_starts(gt, starts)
        self.starts = starts
        sim_cfg = dataclasses.replace(cfg.sim, seed=seed)
        self.world = make_team_world(scene, starts, sim_cfg)
        self.mapper = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        self.tracker = TopologyTracker(gt.shape, cfg.topology, gt)
        self.reference = observable_ground_truth(gt)
        self.counter = KnownCounter(self.reference)
        self.curve: list[tuple[float, float]] = []
        # What each robot's own scans saw (coverage, overlap).
        self.own = [OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
                    for _ in range(n)]
        self.own_counters = [KnownCounter(self.reference) for _ in range(n)]
        self.own_curves: list[list[tuple[float, float]]] = [[] for _ in range(n)]
        self._gt_distance2: np.ndarray | None = None
        self._setup_merging(gt, n)
        if self.team_config.unknown_starts and any(
                getattr(e, "plans_on_ground_truth", False) for e in explorers):
            raise UserInputError("an explorer that plans on the ground truth knows where the "
                                 "robots are: drop --unknown-starts or choose another.")
        robots: Sequence[TeamRobot | TeamGridRobot] = self.world.robots
        self.agents = [RobotAgent(self, i, robot, explorer,
                                  np.random.default_rng([seed, i]) if i else
                                  np.random.default_rng(seed))
                       for i, (robot, explorer) in enumerate(zip(robots, explorers))]
        self.end_reason: str | None = None
        self.masked_returns = 0
        for i, robot in enumerate(robots):
            self._integrate(i, robot.latest_scan)

    def _setup_merging(self, gt: GridMap, n: int) -> None:
        """With unknown starts: each robot but robot 0 with its own map (its ``own``
        mapper, a GVD of its own), an own-frame map to match and its scans kept for the
        merge; the union of the maps for the team's exploration ratio."""
        unknown = self.team_config.unknown_starts and n > 1
        # Each merged robot's correction: the transform from its true pose to its pose in the
        # team's map (None: they are the same, robot 0 and every robot with known starts).
        self.corrections: list[np.ndarray | None] = [None] * n
        self.merged = [True] + [not unknown] * (n - 1)
        self.merges: list[dict[str, Any]] = []
        self.merge_attempts = 0
        self.aligned_scans = 0
        self.kept_walls = 0
        self._trackers: list[TopologyTracker | None] = [None] * n
        self._frames: list[OccupancyMapper | None] = [None] * n
        self._history: list[list[LaserScan]] = [[] for _ in range(n)]
        self._candidates: list[np.ndarray | None] = [None] * n
        self._next_attempt = [0.0] * n
        self.union: OccupancyMapper | None = None
        if not unknown:
            return
        self.union = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        self.union_counter = KnownCounter(self.reference)
        w, h = gt.size_m
        centre = np.array([gt.origin[0] + w / 2, gt.origin[1] + h / 2, 0.0])
        half = 0.5 * math.hypot(w, h) + 1.0
        cells = int(math.ceil(2 * half / gt.resolution))
        for j in range(1, n):
            self._trackers[j] = TopologyTracker(gt.shape, self.config.topology, gt)
            # The own-frame map: a square that holds the building in any orientation (its
            # size and placement are memory only; nothing of them reaches the matcher).
            c = relative_pose(self.starts[j], centre)
            self._frames[j] = OccupancyMapper((cells, cells), (c[0] - half, c[1] - half),
                                              MapperConfig(resolution=gt.resolution))

    def ground_truth_distance2(self) -> np.ndarray:
        """Squared distances to the ground truth's walls and unknown cells (its GVD's), for
        the costmaps of explorers that plan on the ground truth; found once."""
        if self._gt_distance2 is None:
            gt = self.scene.ground_truth
            assert gt is not None  # Checked in __init__.
            gvd = DynamicGVD(gt.shape)
            gvd.update(gt.occupied | (gt.data < 0))
            self._gt_distance2 = gvd.distance2
        return self._gt_distance2

    def map_of(self, index: int) -> tuple[OccupancyMapper, TopologyTracker, KnownCounter]:
        """The map robot ``index`` plans on now: the team's, or before its merge its own."""
        if self.merged[index]:
            return self.mapper, self.tracker, self.counter
        tracker = self._trackers[index]
        assert tracker is not None  # Every unmerged robot has its own.
        return self.own[index], tracker, self.own_counters[index]

    @property
    def all_merged(self) -> bool:
        return all(self.merged)

    # ------------------------------------------------------------------ state

    @property
    def time(self) -> float:
        return self.world.time

    @property
    def ratio(self) -> float:
        return self.curve[-1][1] if self.curve else 0.0

    def view(self, index: int) -> TeamView:
        """The team as robot ``index`` sees it at a decision: the robots that share its map
        (all of them, or before its merge with unknown starts itself alone)."""
        members = [a for a in self.agents if self.merged[a.index]] \
            if self.merged[index] else [self.agents[index]]
        return TeamView([a.index for a in members].index(index),
                        np.array([a.pose for a in members]),
                        [None if a.goal is None else a.goal.copy() for a in members],
                        [a._costmap for a in members],
                        np.array([a.active for a in members]))

    # ------------------------------------------------------------------ mapping

    def _mask(self, index: int, scan: LaserScan) -> LaserScan:
        """The scan with the returns from teammates (within their bounding circles plus
        0.1 m, at their poses now) made invalid (NaN)."""
        others = [r.body_centre for r in self.world.robots if r.index != index]
        if not others or not self.team_config.mask_teammates:
            return scan
        x, y, yaw = scan.pose
        ranges = scan.ranges
        finite = np.isfinite(ranges)
        a = scan.angles + yaw
        ex = x + np.where(finite, ranges, 0.0) * np.cos(a)
        ey = y + np.where(finite, ranges, 0.0) * np.sin(a)
        hit = np.zeros(len(ranges), bool)
        for ox, oy in others:
            hit |= finite & (np.hypot(ex - ox, ey - oy) < BODY_RADIUS + 0.1)
        if not hit.any():
            return scan
        self.masked_returns += int(hit.sum())
        masked = ranges.copy()
        masked[hit] = np.nan
        return dataclasses.replace(scan, ranges=masked)

    def _merged_pose(self, index: int, scan: LaserScan) -> np.ndarray | None:
        """Where a merged robot's scan goes into the team's map: None (its pose) for a
        robot whose start is known, else where the merge's estimate puts it, aligned to
        the map by a scan match (``merge_align``) when one is accepted."""
        correction = self.corrections[index]
        if correction is None:
            return None
        prior = compose_pose(correction, scan.pose)
        cfg = self.team_config.merge_align
        if cfg is None:
            return prior
        match = match_scan(scan_points(scan), self.mapper.grid, prior, cfg)
        self.aligned_scans += match.accepted
        return match.pose if match.accepted else prior

    def _integrate_merged(self, index: int, scan: LaserScan) -> np.ndarray:
        """Maps a merged robot's scan into the team's map; returns the changed cells. A
        robot placed by a merge estimate (``merge_keep_walls``) may not turn the team's
        wall cells free: its residual error would punch holes into them."""
        pose = self._merged_pose(index, scan)
        if pose is None or not self.team_config.merge_keep_walls:
            return self.mapper.integrate(scan, pose)
        state = self.mapper.state.reshape(-1)
        logodds = self.mapper.logodds.reshape(-1)
        walls = np.flatnonzero(state == OCCUPIED)
        saved = logodds[walls]
        changed = self.mapper.integrate(scan, pose)
        lost = state[walls] != OCCUPIED
        if not lost.any():
            return changed
        logodds[walls[lost]] = saved[lost]
        state[walls[lost]] = OCCUPIED
        self.kept_walls += int(lost.sum())
        cols = self.mapper.state.shape[1]
        return changed[~np.isin(changed[:, 0] * cols + changed[:, 1], walls[lost])]

    def _observe(self, mapper: OccupancyMapper, tracker: TopologyTracker,
                 changed: np.ndarray) -> None:
        """Updates ``tracker`` and the costmaps of the robots planning on ``mapper``'s map
        after its ``changed`` cells changed."""
        grid = mapper.grid
        tracker.observe(grid, changed)
        cells = np.concatenate([changed[:, 0] * grid.shape[1] + changed[:, 1],
                                tracker.gvd.last_changed])
        for a in self.agents:
            if a.mapper is mapper:
                a._costmap.update(cells)

    def _integrate(self, index: int, scan: LaserScan) -> None:
        if self.world.physics_fault:
            return
        agent = self.agents[index]
        scan = self._mask(index, agent._deskewed(scan, slice(5, 8)))
        cols = self.mapper.grid.shape[1]
        own = self.own[index]
        own_changed = own.integrate(scan)
        own_ratio = self.own_counters[index].update(own.state, own_changed, cols)
        if self.merged[index]:
            changed = self._integrate_merged(index, scan)
            self._observe(self.mapper, self.tracker, changed)
            ratio = self.counter.update(self.mapper.state, changed, cols)
        else:  # Its own map, its own-frame map, and the scan kept for the merge.
            tracker, frame = self._trackers[index], self._frames[index]
            assert tracker is not None and frame is not None  # Set for every unmerged robot.
            self._observe(own, tracker, own_changed)
            frame.integrate(scan, relative_pose(self.starts[index], scan.pose))
            self._history[index].append(scan)
        if self.union is not None:
            union_changed = self.union.integrate(scan)
            union_ratio = self.union_counter.update(self.union.state, union_changed, cols)
            if not self.all_merged:
                ratio = union_ratio
        self.curve.append((scan.stamp, ratio))
        self.own_curves[index].append((scan.stamp, own_ratio))
        if self.observer is not None and hasattr(self.observer, "on_scan"):
            self.observer.on_scan(self, index, scan)

    # ------------------------------------------------------------------ stepping

    def _check_end(self) -> bool:
        if self.end_reason is not None:
            return True
        cfg = self.config
        t = self.time
        if self.ratio >= cfg.target_ratio:
            self.end_reason = "explored"
        elif t >= cfg.max_time - 1e-9:
            self.end_reason = "time_limit"
        elif self.world.physics_fault:
            self.end_reason = "physics_fault"
        elif not all(r.is_upright for r in self.world.robots):
            self.end_reason = "tipped_over"
        elif all(a.retired is not None for a in self.agents):
            self.end_reason = "lingering"
        return self.end_reason is not None

    def _set_teammates(self) -> None:
        centres = np.array([r.body_centre for r in self.world.robots])
        for a in self.agents:
            a._costmap.set_teammates(np.delete(centres, a.index, axis=0))

    def _decide(self, agent: RobotAgent) -> None:
        """Runs ``agent``'s decision if one is due; idles it when it finds nothing."""
        t = self.time
        if agent.idle_until is not None:
            if t < agent.idle_until:
                return
            agent.idle_until = None
            agent._decision_due = True
            resumed = True
        else:
            resumed = False
        if agent.decision_due():
            if agent._decision_scan():
                return
            if not agent._decide():
                agent.goal = None
                agent.navigator.status = NavStatus.IDLE
                agent._end_wait(t)
                if not resumed:
                    agent.idle_since = t
                agent.idle_until = t + self.team_config.idle_retry
                return
        if resumed:
            agent.idle_time += t - agent.idle_since
            agent.navigator.restart_linger_clock(agent.pose, t)

    def _all_idle(self) -> bool:
        """True when no robot explores and one at least is idle: each finds nothing (asked
        once more now) or has retired."""
        if any(a.active for a in self.agents) or all(a.retired for a in self.agents):
            return False
        for a in self.agents:
            if a.retired is None:
                a.idle_until = self.time  # Due now: ask again.
                self._decide(a)
        return not any(a.active for a in self.agents)

    def _resolve_blocks(self) -> None:
        """Two robots that block each other (each waiting, or in contact) for
        ``yield_after`` seconds: the higher-indexed one yields."""
        t = self.time
        tc = self.team_config
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
            poses = self.world.poses()
            d = np.hypot(*(poses[:, :2] - a.pose[:2]).T)
            d[a.index] = np.inf
            other = self.agents[int(np.argmin(d))]
            # A robot that stands still for good (idle or retired) moves aside for the one it
            # blocks; of two blocked robots the higher-indexed one moves aside; a robot
            # blocked by one driving on moves aside itself.
            if not other.active and other._yield_goal is None:
                if other.yield_way(a):
                    a._blocked_since = None
                continue
            other_blocked = other._blocked_since is not None
            if (other_blocked and a.index > other.index) or \
                    (not other_blocked and a.waiting_since is not None and
                     t - a.waiting_since >= tc.yield_after):
                if a.yield_way(other):
                    a._blocked_since = None

    def step(self) -> bool:
        """One control period for every robot; False once the episode has ended."""
        if self._check_end():
            return False
        t = self.time
        self._set_teammates()
        decided = [len(a.goals) for a in self.agents]
        for a in self.agents:
            if a.retired is not None:
                continue
            if a.active and a._yield_goal is None and a._lingered(a.pose, t):
                a.retired = "lingering"
                a.navigator.status = NavStatus.IDLE
                a.goal = None
                continue
            self._decide(a)
        if self._check_end():
            return False
        if self._all_idle():
            self.end_reason = "no_frontiers"
            return False
        self._resolve_blocks()
        if self.observer is not None and hasattr(self.observer, "on_goal"):
            for a, n in zip(self.agents, decided):
                for when, x, y in a.goals[n:]:
                    self.observer.on_goal(self, a.index, when, x, y)
        poses = []
        for a in self.agents:
            if a.active or a._yield_goal is not None:
                poses.append(a.command())
            else:
                a.sim.command(0.0, 0.0)
                poses.append(a.pose)
        scans = self.world.step(1.0 / self.config.control_rate_hz)
        for k in range(max((len(s) for s in scans), default=0)):
            for i, robot_scans in enumerate(scans):
                if k < len(robot_scans):
                    self._integrate(i, robot_scans[k])
        for a, pose in zip(self.agents, poses):
            a.record_visit(pose)
        if not self.all_merged:
            self._try_merges()
        if self.observer is not None and hasattr(self.observer, "on_step"):
            self.observer.on_step(self)
        return True

    # ------------------------------------------------------------------ map merging

    def _try_merges(self) -> None:
        """Matches each unmerged robot's own-frame map against the team's map once every
        ``merge_period``; merges it when two successive accepted matches agree."""
        t = self.time
        tc = self.team_config
        for j in range(len(self.agents)):
            if self.merged[j] or t < self._next_attempt[j]:
                continue
            self._next_attempt[j] = t + tc.merge_period
            self.merge_attempts += 1
            frame = self._frames[j]
            assert frame is not None  # Set for every unmerged robot.
            match = merge_maps(self.mapper.grid, frame.grid, tc.merge)
            previous, self._candidates[j] = self._candidates[j], None
            if not match.accepted:
                continue
            self._candidates[j] = match.pose
            if previous is not None:
                d = relative_pose(previous, match.pose)
                if math.hypot(d[0], d[1]) <= tc.merge_agreement[0] and \
                        abs(d[2]) <= tc.merge_agreement[1]:
                    self._merge(j, match)

    def _merge(self, j: int, match: Any) -> None:
        """Merges robot ``j``'s map into the team's with ``match``'s pose of its start."""
        estimate = np.asarray(match.pose, float)
        truth = np.asarray(self.starts[j], float)
        # The correction takes j's true pose to its pose in the team's map: the estimated
        # start composed with its pose relative to its true start.
        correction = compose_pose(estimate, relative_pose(truth, np.zeros(3)))
        self.corrections[j] = correction
        self.merged[j] = True
        changed = [self.mapper.integrate(scan, compose_pose(correction, scan.pose))
                   for scan in self._history[j]]
        self._history[j] = []
        self._frames[j] = None
        self._trackers[j] = None
        self._candidates[j] = None
        cells = np.unique(np.concatenate(changed), axis=0) if changed else \
            np.zeros((0, 2), np.int64)
        agent = self.agents[j]
        agent.use_map(self.mapper, self.tracker, self.counter)
        self._observe(self.mapper, self.tracker, cells)
        ratio = self.counter.update(self.mapper.state, cells, self.mapper.grid.shape[1])
        self._set_teammates()
        # Its plans were on its own map: it decides anew on the team's.
        agent.goal = None
        agent.navigator.status = NavStatus.IDLE
        agent._decision_due = True
        agent._end_wait(self.time)
        if agent.idle_until is not None:
            agent.idle_until = self.time
        error = relative_pose(truth, estimate)
        self.merges.append({
            "robot": j, "time_s": round(self.time, 3),
            "error_m": round(float(math.hypot(estimate[0] - truth[0],
                                              estimate[1] - truth[1])), 4),
            "error_deg": round(math.degrees(abs(wrap_angle(float(error[2])))), 4),
            "estimate": [round(float(v), 4) for v in estimate],
            "inliers": round(match.inliers, 4), "conflict": round(match.conflict, 5),
            "wall_overlap_m": round(match.wall_overlap, 2)})
        if self.all_merged:  # From now on the team's ratio is its map's.
            self.curve.append((self.time, ratio))

    def run(self) -> TeamEpisodeResult:
        """Steps to the end; Ctrl-C ends the episode as ``interrupted`` (as
        :meth:`Episode.run`)."""
        with SigintFlag() as flag:
            while not flag.raised and self.step():
                pass
        if flag.raised:
            self.end_reason = "interrupted"
            raise Interrupted(self.result())  # type: ignore[arg-type]
        return self.result()

    # ------------------------------------------------------------------ results

    def result(self) -> TeamEpisodeResult:
        curve = np.array(self.curve).reshape(-1, 2)
        grid = self.mapper.grid
        logs = [r.kinematics() for r in self.world.robots]
        paths = [log.path_length() for log in logs]
        t_end = float(curve[-1, 0]) if len(curve) else 0.0
        known_team = self.counter.count
        own_known = [c.count for c in self.own_counters]
        t = self.time
        per_robot = []
        for a, log, path, known in zip(self.agents, logs, paths, own_known):
            odom = log.odom_pose[:, :2]
            wait = a.wait_time + (t - a.waiting_since if a.waiting_since is not None else 0.0)
            idle = a.idle_time + (t - a.idle_since if a.idle_until is not None else 0.0)
            per_robot.append({
                "robot": a.sim.name,
                "start": [round(v, 4) for v in self.starts[a.index]],
                "path_length_m": round(path, 3),
                "odometry_path_length_m": round(
                    float(np.linalg.norm(np.diff(odom, axis=0), axis=1).sum()), 3),
                "coverage": round(known / self.counter.total, 5),
                "collisions": int(a.sim.collisions),
                "robot_contacts": int(a.sim.robot_contacts),
                "decisions": len(a.goals),
                "fallbacks": a.fallbacks,
                "reoffers": a.reoffers,
                "given_up": a.blacklist.reasons(),
                "waits": a.waits,
                "wait_time_s": round(wait, 3),
                "yields": a.yields,
                "idle_time_s": round(max(idle, 0.0), 3),
                "state": a.retired or ("idle" if a.idle_until is not None else "exploring"),
                "mean_speed_mps": round(path / t_end, 4) if t_end > 0 else 0.0,
            })
        metrics: dict[str, Any] = {
            "robots": len(self.agents),
            "iou": round(iou(grid, self.reference), 5),
            "exploration_ratio": round(float(curve[-1, 1]), 5) if len(curve) else 0.0,
            "exploration_time_s": round(t_end, 3),
            **{key: first_time_at(curve, level) for level, key in TEAM_MILESTONES},
            "path_length_m": round(float(sum(paths)), 3),
            "max_path_length_m": round(float(max(paths)), 3),
            "overlap_ratio": round(sum(own_known) / max(known_team, 1) - 1.0, 5),
            "collisions": int(sum(r.collisions for r in self.world.robots)),
            "robot_collisions": int(self.world.robot_collisions),
            "end_reason": self.end_reason or "running",
            "decisions": sum(len(a.goals) for a in self.agents),
            "waits": sum(a.waits for a in self.agents),
            "yields": sum(a.yields for a in self.agents),
            "masked_returns": self.masked_returns,
            "localization": self.config.localization,
            "per_robot": per_robot,
        }
        if self.union is not None:
            errors = [(m["error_m"], m["error_deg"]) for m in self.merges]
            metrics.update({
                "unknown_starts": True,
                "merged": self.all_merged,
                "merge_time_s": self.merges[-1]["time_s"] if self.all_merged else None,
                "merge_error_m": max(e[0] for e in errors) if errors else None,
                "merge_error_deg": max(e[1] for e in errors) if errors else None,
                "merge_attempts": self.merge_attempts,
                "aligned_scans": self.aligned_scans,
                "kept_walls": self.kept_walls,
                "merges": self.merges,
                # The team's map against the ground truth (the union's until all merged).
                "team_map_ratio": round(self.counter.count / self.counter.total, 5),
            })
        return TeamEpisodeResult(
            metrics, curve, [np.array(c).reshape(-1, 2) for c in self.own_curves], logs,
            GridMap(grid.data.copy(), grid.resolution, grid.origin),
            [np.array(a.goals).reshape(-1, 3) for a in self.agents], list(self.starts))


__all__ = ["TEAM_END_REASONS", "TEAM_MILESTONES", "RobotAgent", "TeamConfig", "TeamEpisode",
           "TeamEpisodeResult", "TeamView"]
