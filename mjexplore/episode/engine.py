"""One exploration episode: an explorer in a scene, in full physics, measured in sim time.

Every 0.1 s of simulated time the navigator commands the robot; every scan is mapped and
the GVD updated; when a goal is reached (within zeta), vanishes (its frontier got seen)
or is given up, the explorer is asked for the next one.

Exploration is over only when no frontier of the known map can be reached (one rule for
every explorer): an explorer that sees nothing left while the map shows a reachable
frontier is overruled, and the robot goes to the nearest one (counted in ``fallbacks``).
Goals are given up (:mod:`mjexplore.navigation.blacklist`) when no path leads to them,
when the path to them stops shrinking, when the robot lingers on the way, or when the robot
stood at them (within zeta) and their frontier stayed open; given-up goals are forgotten
when the map around them changes and offered again when nothing else is left. So a
frontier counts as unreachable when no path leads to it, when the robot failed to get to
it ``max_attempts`` times with the map around it unchanged, or when the robot stood at it
without seeing past it.

The episode ends when the exploration ratio reaches the target (98.5 % by default:
``explored``), when no frontier is reachable in that sense (``no_frontiers``; ``lost``
when the robot's own estimate lies off its map or inside a wall, so that nothing can be
planned from it, which only a localiser's estimate can), when the
robot stays on one spot though it has tried ``linger_strikes`` goals there
(``lingering``, the paper's "terminated unexpectedly"), tips over (``tipped_over``), when
the physics fails (``physics_fault``: non-finite state or MuJoCo's instability reset; the
broken scans are not mapped), or at the time cap (``time_limit``). ``run`` turns Ctrl-C
into ``interrupted`` with everything recorded so far intact.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any, Protocol, cast

import cv2
import numpy as np

from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.episode.metrics import KnownCounter, episode_metrics, pose_errors
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.errors import UserInputError
from mjexplore.mapping.localization import FusedLocalizer, LocalizerConfig
from mjexplore.mapping.metrics import exploration_ratio, iou, observable_ground_truth
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.mapping.scan_matching import ScanMatchingLocalizer, deskew_scan
from mjexplore.maps import GridMap
from mjexplore.navigation.blacklist import BlacklistConfig, GoalBlacklist
from mjexplore.navigation.navigator import Navigator, NavigatorConfig, NavStatus
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.scenes.scene import SceneFiles, check_start
from mjexplore.sim.kinematics import KinematicsLog
from mjexplore.sim.simulator import SimConfig
from mjexplore.sim.world import make_world
from mjexplore.topology.frontiers import frontier_mask
from mjexplore.topology.pipeline import TopologyConfig, TopologyTracker

LOCALIZATIONS = ("ground_truth", "odometry", "scan_matching")
END_REASONS = ("explored", "no_frontiers", "lost", "lingering", "tipped_over", "time_limit",
               "decision_limit", "physics_fault", "interrupted")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EpisodeConfig:
    """Episode settings.

    Attributes:
        max_time: Time cap in simulated seconds.
        target_ratio: Exploration ratio at which the scene counts as explored.
        control_rate_hz: Navigator rate.
        localization: Where the robot believes it is: 'ground_truth', 'odometry' (wheel
            odometry dead-reckoned from the start pose) or 'scan_matching' (odometry
            corrected by matching each scan against the map). With anything but ground
            truth, everything the robot does uses the estimate: mapping (scans posed at
            their timestamps), navigation, goals, lingering and the explorer's state. The
            exploration ratio is measured at the true pose (the same scans mapped where
            they were really taken), so the episode ends on what was seen; IoU compares the
            robot's own map with the ground truth, so distortion shows.
        sim: World settings (dynamics: physics, kinematic or grid; profile, lidar).
        navigator: Navigation settings (zeta, replanning, lingering).
        planner: Costmap settings.
        topology: Frontier and GVD settings.
        blacklist: When given-up goals are forgotten and offered again.
        start_jitter: (metres, radians) half-widths of the seeded uniform offset of the start
            pose from the scene's (kept only where the robot fits), so that seeds differ.
        progress_timeout: A goal whose path has not become 0.25 m shorter for this many
            seconds is given up (a gap the costmap allows but the body does not pass); a
            replanned path more than 1 m longer restarts the clock, up to
            ``longer_route_restarts`` times per goal (a route that flips between two ways
            around would otherwise hold the goal forever).
        longer_route_restarts: See ``progress_timeout``.
        linger_strikes: Goals given up for lingering on one spot before the episode ends
            as ``lingering``.
    """

    max_time: float = 1800.0
    target_ratio: float = 0.985
    control_rate_hz: float = 10.0
    localization: str = "ground_truth"
    sim: SimConfig = dataclasses.field(default_factory=SimConfig)
    navigator: NavigatorConfig = dataclasses.field(default_factory=NavigatorConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    topology: TopologyConfig = dataclasses.field(default_factory=TopologyConfig)
    blacklist: BlacklistConfig = dataclasses.field(default_factory=BlacklistConfig)
    start_jitter: tuple[float, float] = (0.25, 0.3)
    progress_timeout: float = 20.0
    longer_route_restarts: int = 3
    linger_strikes: int = 3

    def __post_init__(self) -> None:
        if self.localization not in LOCALIZATIONS:
            raise UserInputError(f"localization {self.localization!r} is unknown: use one of "
                                 f"{', '.join(LOCALIZATIONS)}.")
        if not (self.max_time > 0 and self.control_rate_hz > 0):
            raise ValueError("max_time and control_rate_hz must be > 0")
        if not 0 < self.target_ratio <= 1:
            raise ValueError("target_ratio must be in (0, 1]")
        if self.progress_timeout <= 0 or min(self.start_jitter) < 0 or \
                self.linger_strikes < 0 or self.longer_route_restarts < 0:
            raise ValueError("start_jitter, linger_strikes and longer_route_restarts must be "
                             ">= 0, progress_timeout > 0")


@dataclasses.dataclass
class EpisodeResult:
    """What an episode produced.

    Attributes:
        metrics: The paper's metrics and more (see :func:`episode_metrics`).
        ratio_curve: (n, 2) simulated time (s) and exploration ratio after each scan.
        kinematics: Velocity and acceleration log.
        grid: The final map.
        goals: (m, 3) decision time (s) and goal (x, y).
    """

    metrics: dict[str, Any]
    ratio_curve: np.ndarray
    kinematics: KinematicsLog
    grid: GridMap
    goals: np.ndarray


class SigintFlag:
    """Within the block, the first SIGINT sets ``raised`` instead of raising (main thread
    only; elsewhere SIGINT keeps its usual effect)."""

    def __init__(self) -> None:
        self.raised = False
        self._previous: Callable[[int, FrameType | None], Any] | int | None = None

    def _handle(self, signum, frame) -> None:
        if self.raised:
            raise KeyboardInterrupt
        self.raised = True

    def __enter__(self) -> SigintFlag:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during :meth:`Episode.run`; carries the result of the episode so far."""

    def __init__(self, result: EpisodeResult) -> None:
        super().__init__("episode interrupted")
        self.result = result


class _Configured(Protocol):
    """What :meth:`Episode._jittered_start` reads of its owner (a team episode's too)."""

    config: EpisodeConfig


class Episode:
    """Runs one episode; steps are exposed so that callers (logging, video) can watch.

    Args:
        scene: The scene.
        explorer: The explorer.
        seed: Seed for the explorer and sensor noise.
        config: Episode settings.
        observer: Optional object with ``on_scan``, ``on_decision`` and ``on_step`` hooks.
    """

    def __init__(self, scene: SceneFiles, explorer: Explorer, seed: int,
                 config: EpisodeConfig | None = None, observer: Any = None) -> None:
        if scene.ground_truth is None:
            raise ValueError("episodes need a scene with a ground-truth map")
        self.config = config or EpisodeConfig()
        cfg = self.config
        self.scene = scene
        self.explorer = explorer
        self.observer = observer
        sim_cfg = dataclasses.replace(cfg.sim, seed=seed)
        self.sim = make_world(scene, sim_cfg)
        gt = scene.ground_truth
        self.sim.reset(self._jittered_start(scene, gt, np.random.default_rng(seed)))
        self.mapper = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        # Without ground-truth localisation the robot maps where it believes it is, and a
        # second mapper maps the same scans where they were taken: what was really seen.
        self.localizer: ScanMatchingLocalizer | FusedLocalizer | None = None
        self._seen = self.mapper
        if cfg.localization == "scan_matching":
            self.localizer = FusedLocalizer(
                self.sim.pose, odom_pose=self.sim.odom_pose,
                config=LocalizerConfig.for_lidar(self.sim.lidar.config,
                                                 cfg.sim.odometry_heading))
        elif cfg.localization != "ground_truth":
            self.localizer = ScanMatchingLocalizer(self.sim.pose, odom_pose=self.sim.odom_pose)
        if self.localizer is not None:
            self._seen = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        self._positions: list[tuple[float, float, float, float]] = []  # Estimate, truth.
        self.tracker = TopologyTracker(gt.shape, cfg.topology, gt)
        self.reference = observable_ground_truth(gt)
        self.counter = KnownCounter(self.reference)
        self.navigator = Navigator(self.sim.profile, cfg.navigator)
        self._costmap = Costmap(self.mapper.grid, self.tracker.gvd.distance2, cfg.planner)
        # An explorer that knows the ground truth (the oracle) also navigates on it.
        self._static_costmap: Costmap | None = None
        if getattr(explorer, "plans_on_ground_truth", False):
            self._static_costmap = cast(Any, explorer).ground_truth_costmap(
                ExplorationState(gt, self.sim.pose, 0.0, [], self._costmap, np.zeros((0, 2)),
                                 ground_truth=gt))
        explorer.reset(np.random.default_rng(seed))
        self._start_deciding()
        self.curve: list[tuple[float, float]] = []
        self.goals: list[tuple[float, float, float]] = []
        self.visited: list[np.ndarray] = []
        self.end_reason: str | None = None
        self._integrate(self.sim.latest_scan)

    # ------------------------------------------------------------------ internals

    def _start_deciding(self) -> None:
        """The decision and navigation state of a fresh episode: no goal, no blacklist, no
        strikes (the engine's and each team robot's)."""
        self.goal: np.ndarray | None = None
        self._goal_window: tuple[tuple, tuple[slice, slice]] | None = None  # (goal, cells)
        self._decision_due = False
        self._best_distance = math.inf
        self._best_time = 0.0
        self._route_restarts = 0
        self._decided_at = 0.0
        self._fallback = NearestFrontier()
        self.fallbacks = 0
        self.reoffers = 0
        self.blacklist = GoalBlacklist(self.config.blacklist)
        self._linger_strikes = 0
        self._stuck = 0  # Control periods since the robot got stuck (0: it is not).
        self._stuck_at = np.zeros(2)
        self._strike_at: np.ndarray | None = None

    def _jittered_start(self: _Configured, scene: SceneFiles, gt: GridMap,
                        rng: np.random.Generator) -> tuple[float, float, float]:
        dxy, dyaw = self.config.start_jitter
        x, y, yaw = scene.start
        offset = rng.uniform(-1.0, 1.0, size=3) * (dxy, dxy, dyaw)
        pose = (x + offset[0], y + offset[1], yaw + offset[2])
        try:
            check_start(gt, pose)
        except UserInputError:
            return (x, y, pose[2])
        return pose

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of ``base_link`` in ``map`` as the robot believes it (the true pose
        with ground-truth localisation)."""
        return self.sim.pose if self.localizer is None else self.localizer.pose

    def _deskewed(self, scan, columns: slice):
        """The scan as if all its beams were cast from ``base_scan`` at its stamp, undone
        along the base's trajectory in ``kinematics_rows[:, columns]`` (5:8 the true poses,
        8:11 the odometry's); the scan itself when its beams were cast at once."""
        rows = self.sim.kinematics_rows
        if scan.time_increment == 0 or len(rows) < 2:
            return scan
        first = scan.stamp + min(scan.time_increment * (len(scan.ranges) - 1), 0.0)
        lo = max(int(np.searchsorted(rows[:, 0], first)) - 1, 0)
        return deskew_scan(scan, trajectory=(rows[lo:, 0], rows[lo:, columns]))

    def _localize(self, scan):
        """Updates the pose estimate to the scan's stamp; the scan as the robot maps it
        (deskewed when its beams were taken over time) and its sensor pose."""
        loc = self.localizer
        rows = self.sim.kinematics_rows
        if len(rows) == 0:
            odom, truth, stamp = self.sim.odom_pose, self.sim.pose, self.sim.time
        else:
            recent = rows[-40:]
            k = int(np.argmin(np.abs(recent[:, 0] - scan.stamp)))  # Scans fall on samples.
            odom, truth, stamp = recent[k, 8:11], recent[k, 5:8], float(recent[k, 0])
        loc.advance(odom, stamp)
        scan = self._deskewed(scan, slice(8, 11))
        if self.config.localization == "scan_matching":
            loc.correct(scan, self.mapper)
        estimate = loc.pose
        self._positions.append((estimate[0], estimate[1], truth[0], truth[1]))
        return scan, loc.sensor_pose

    def _integrate(self, scan) -> None:
        if self.sim.physics_fault:
            return  # A broken state would map garbage; the episode ends at the next check.
        grid = self.mapper.grid
        seen = None
        # What was seen: every beam from where it was really cast (the LDS-01's are spread
        # over its rotation).
        true_scan = self._deskewed(scan, slice(5, 8))
        if self.localizer is not None:
            seen = self._seen.integrate(true_scan)
            scan, sensor_pose = self._localize(scan)
            changed = self.mapper.integrate(scan, sensor_pose)
        else:
            changed = self.mapper.integrate(true_scan)
        self.tracker.observe(grid, changed)
        if self._costmap is not None:
            self._costmap.update(np.concatenate([changed[:, 0] * grid.shape[1] + changed[:, 1],
                                                 self.tracker.gvd.last_changed]))
        ratio = self.counter.update(self._seen.state, changed if seen is None else seen,
                                    grid.shape[1])
        self.curve.append((scan.stamp, ratio))
        if self.observer is not None:
            self.observer.on_scan(self, scan)

    def costmap(self) -> Costmap:
        """The planner's costmap (kept current as scans arrive)."""
        return self._static_costmap or self._costmap

    def _goal_still_open(self) -> bool:
        """A frontier goal stays worth driving to while unknown cells lie next to it; an
        explorer with other goals can say itself (``goal_open(grid)``)."""
        if getattr(self.explorer, "waypoint", False):
            # A waypoint (a TER node that is not a frontier) is driven to until reached.
            return self.navigator.status == NavStatus.ACTIVE
        if hasattr(self.explorer, "goal_open"):
            verdict = self.explorer.goal_open(self.mapper.grid)
            if verdict is not None:
                return verdict
        # Asked every control period: the cells around the goal are found once per goal.
        assert self.goal is not None  # Asked only once a goal was adopted.
        goal = tuple(self.goal)
        if self._goal_window is None or self._goal_window[0] != goal:
            grid = self.mapper.grid
            r, c = grid.world_to_cell(self.goal)
            k = max(1, int(round(0.3 / grid.resolution)))
            self._goal_window = goal, np.s_[max(r - k, 0):r + k + 1, max(c - k, 0):c + k + 1]
        return bool((self.mapper.state[self._goal_window[1]] < 0).any())

    def decision_state(self) -> ExplorationState:
        """What the explorer sees now (frontiers already filtered by the blacklist)."""
        grid = self.mapper.grid
        cfg = self.config
        self.blacklist.forget_changed(grid)
        state = ExplorationState(grid, self.pose, self.sim.time, [], self.costmap(),
                                 np.array(self.visited).reshape(-1, 2),
                                 blacklist=self.blacklist.points(),
                                 ground_truth=self.scene.ground_truth,
                                 blacklist_radius=cfg.blacklist.radius,
                                 sensor_range=self.sim.lidar.config.range_max,
                                 target_ratio=cfg.target_ratio,
                                 extras={"tracker": self.tracker})
        frontiers = self.tracker.frontiers(grid)
        if frontiers:
            allowed = state.allowed([f.goal for f in frontiers])
            state.frontiers = [f for f, ok in zip(frontiers, allowed) if ok]
        return state

    def adopt_goal(self, goal: np.ndarray, state: ExplorationState | None = None) -> bool:
        """Makes ``goal`` (x, y, metres) the navigation goal.

        Returns:
            False if the goal was refused and given up: no path leads to it, or it lies
            within zeta yet its frontier is still open (the lidar cannot see it from here).
        """
        goal = np.asarray(goal, float)
        if (self.goal is not None and np.array_equal(goal, self.goal) and
                self.navigator.status == NavStatus.ACTIVE):
            # A periodic re-plan that keeps the goal: carry on, progress clock running.
            self._decision_due = False
            self._decided_at = self.sim.time
            return True
        self.goal = goal
        self.goals.append((self.sim.time, *self.goal))
        if self.observer is not None:
            self.observer.on_decision(self, state if state is not None else self.decision_state())
        pose = self.pose
        near = np.hypot(*(self.goal - pose[:2])) <= self.config.navigator.goal_tolerance
        if near and not getattr(self.explorer, "waypoint", False) and self._goal_still_open():
            self._give_up("seen_open")
            return False
        if not self.navigator.set_goal(self.goal, self.costmap(), pose, self.sim.time):
            self._give_up("no_path")
            return False
        self._best_distance = self.navigator.remaining_length(pose)
        self._best_time = self._decided_at = self.sim.time
        self._route_restarts = 0
        self._decision_due = False
        return True

    def _give_up(self, reason: str) -> None:
        """Blacklists the current goal for ``reason`` and asks for a new one."""
        assert self.goal is not None  # Given up only once adopted.
        self.blacklist.add(self.goal, reason, self.mapper.grid)
        self.navigator.status = NavStatus.NO_PATH
        self._decision_due = True

    def _decide(self) -> bool:
        """Asks the explorer for a goal; False when exploration is over.

        An explorer's "nothing left" is checked against the map (:meth:`decide_fallback`),
        so an explorer that misses small or distant frontiers (one that drops frontiers
        under a size, a coarse view) does not end the episode early.
        """
        for _ in range(8):
            state = self.decision_state()
            goal = self.explorer.select_goal(state)
            if goal is None:
                return self.decide_fallback()
            if self.adopt_goal(goal, state):
                return True
        return True  # Keep going; the next tick decides again.

    def decide_fallback(self) -> bool:
        """The engine's own decision, for when the explorer has none; False when
        exploration is over (no frontier can be reached).

        The robot goes to the nearest frontier that is not blacklisted (counted in
        ``fallbacks``). When none is left, the goals given up for want of a path or of
        progress are offered again (counted in ``reoffers``), and any frontier cell within
        zeta of the reachable space counts (clusters too small or too thin to be frontiers
        of their own, goals that lie off a frontier's reachable side).
        """
        for _ in range(8):
            state = self.decision_state()
            goal = self._last_resort(state)
            while goal is None and self.blacklist.reoffer():
                self.reoffers += 1
                state = self.decision_state()
                goal = self._last_resort(state)
            if goal is None:
                return False
            self.fallbacks += 1
            if self.adopt_goal(goal, state):
                return True
        return True  # Keep going; the next tick decides again.

    def _last_resort(self, state: ExplorationState) -> np.ndarray | None:
        """The nearest frontier by path, else the nearest frontier cell (an unknown cell
        next to free space) that a traversable cell within zeta of it connects to the
        robot; None if there is none (neither counting blacklisted goals)."""
        goal = self._fallback.select_goal(state)
        if goal is not None:
            return goal
        grid = state.grid
        cells = np.argwhere(frontier_mask(grid))
        if len(cells) == 0:
            return None
        cells = cells[state.allowed(grid.cell_to_world(cells))]
        if len(cells) == 0:
            return None
        near = np.zeros(grid.shape, np.uint8)
        near[cells[:, 0], cells[:, 1]] = 1
        k = int(round(self.config.navigator.goal_tolerance / grid.resolution))
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
        targets = cv2.dilate(near, disk).astype(bool) & state.costmap.traversable
        dist = state.costmap.distances_from(state.pose[:2], targets, stop_after=1)
        reached = np.argwhere(np.isfinite(dist) & targets)
        if len(reached) == 0:
            return None
        entry = reached[np.argmin(dist[reached[:, 0], reached[:, 1]])]
        return grid.cell_to_world(cells[np.argmin(np.hypot(*(cells - entry).T))])

    # ------------------------------------------------------------------ stepping

    def _check_end(self) -> bool:
        """Sets ``end_reason`` if the episode is over; True then."""
        if self.end_reason is not None:
            return True
        cfg = self.config
        sim = self.sim
        t = sim.time
        if self.curve[-1][1] >= cfg.target_ratio:
            self.end_reason = "explored"
        elif t >= cfg.max_time - 1e-9:
            self.end_reason = "time_limit"
        elif sim.physics_fault:
            self.end_reason = "physics_fault"
        elif not sim.is_upright:
            self.end_reason = "tipped_over"
        elif self._lingered(self.pose, t):
            self.end_reason = "lingering"
        return self.end_reason is not None

    def _lingered(self, pose: np.ndarray, t: float) -> bool:
        """True when the robot has stayed on one spot through ``linger_strikes`` goals;
        before that, a goal the robot lingers on is given up and the clock restarts."""
        radius = self.config.navigator.linger_radius
        if self._strike_at is not None and np.hypot(*(pose[:2] - self._strike_at)) > radius:
            self._linger_strikes, self._strike_at = 0, None
        if not self.navigator.lingering(pose, t):
            return False
        if self.goal is None or self._linger_strikes >= self.config.linger_strikes:
            return True
        self._linger_strikes += 1
        self._strike_at = pose[:2].copy()
        self._give_up("lingered")
        self.navigator.restart_linger_clock(pose, t)
        return False

    def decision_due(self) -> bool:
        """Whether the explorer must choose a goal before the next control period (the
        goal was reached, vanished, failed or made no progress, or the explorer re-plans
        every ``replan_period`` seconds). Evaluated once per control period; stays True
        until a goal is adopted."""
        if self._decision_due:
            return True
        cfg = self.config
        pose, t = self.pose, self.sim.time
        period = getattr(self.explorer, "replan_period", None)
        if period is not None and self.goal is not None and t - self._decided_at >= period:
            self._decision_due = True
            return True
        if self.goal is not None and self.navigator.status == NavStatus.ACTIVE:
            d = self.navigator.remaining_length(pose)
            longer = d > self._best_distance + 1.0 and \
                self._route_restarts < cfg.longer_route_restarts
            if d < self._best_distance - 0.25 or longer:
                # Closer along the path, or a longer route replanned: the clock restarts.
                self._route_restarts += longer
                self._best_distance, self._best_time = d, t
            elif t - self._best_time > cfg.progress_timeout:
                self._give_up("no_progress")
                return True
        if self.goal is None or self.navigator.status != NavStatus.ACTIVE or \
                not self._goal_still_open():
            if self.navigator.status == NavStatus.REACHED and self._goal_still_open():
                # Reached, yet still next to unknown space: the lidar cannot see it from
                # here (a blind corner, a gap too small).
                self._give_up("seen_open")
            self._decision_due = True
        return self._decision_due

    def control(self) -> None:
        """One control period of navigation towards the current goal."""
        pose = self.command()
        for scan in self.sim.step(1.0 / self.config.control_rate_hz):
            self._integrate(scan)
        self.record_visit(pose)
        if self.observer is not None:
            self.observer.on_step(self)

    def command(self) -> np.ndarray:
        """Commands the robot for the next control period: the navigator's twist towards
        the goal, or the recovery's while the robot is stuck; returns the pose it steered
        from."""
        sim = self.sim
        pose = self.pose
        v, w = self.navigator.update(pose, sim.time, self.costmap)
        # Stuck: collided, and not yet 0.25 m away from where it first did.
        if self._stuck and np.hypot(*(pose[:2] - self._stuck_at)) > 0.25:
            self._stuck = 0
        if sim.in_collision or self._stuck:
            if not self._stuck:
                self._stuck_at = pose[:2].copy()
            self._stuck += 1
            # Recovery, two seconds each in turn until the robot is out: back off the
            # wall, the navigator's own command, turn one way, turn the other (a wedge
            # may let the body out one way only).
            p = sim.profile
            v, w = ((-0.5 * p.max_linear_speed, 0.0), (v, w), (0.0, p.max_angular_speed),
                    (0.0, -p.max_angular_speed))[(self._stuck - 1) // 20 % 4]
        sim.command(v, w)
        return pose

    def record_visit(self, pose: np.ndarray) -> None:
        """Adds ``pose``'s position to ``visited`` once it is 0.25 m from the last one."""
        last = self.visited[-1] if self.visited else None
        if last is None or np.hypot(pose[0] - last[0], pose[1] - last[1]) > 0.25:
            self.visited.append(pose[:2].copy())

    def step(self) -> bool:
        """One control period; returns False once the episode has ended."""
        if self._check_end():
            return False
        if self.decision_due():
            if self._decision_scan():
                return False
            if not self._decide():
                self.end_reason = "lost" if self._lost() else "no_frontiers"
                return False
        self.control()
        return True

    def _lost(self) -> bool:
        """True when the robot's estimate has no traversable cell of its map near it (off
        the map, or inside a wall): planning from it fails whatever is left to explore."""
        return (self.localizer is not None and
                self.costmap().nearest_traversable(self.pose[:2]) < 0)

    def _decision_scan(self) -> bool:
        """Maps the scan that a world scanning by travel (the grid world's ``scan_travel``)
        skipped at this instant, so that each decision sees the map from where the robot
        stands; True if the episode ended with it."""
        scan = self.sim.scan_now()
        if scan is None:
            return False
        self._integrate(scan)
        return self._check_end()

    def run_to_decision(self) -> bool:
        """Runs control periods until a decision is due (True) or the episode ends (False);
        for callers that choose goals themselves (the Gymnasium env)."""
        while not self._check_end():
            if self.decision_due():
                return not self._decision_scan()
            self.control()
        return False

    def run(self) -> EpisodeResult:
        """Steps to the end.

        Ctrl-C (SIGINT) is taken between control periods (never inside MuJoCo or numba
        code): the episode ends as ``interrupted`` and :class:`Interrupted`, carrying the
        result so far, is raised. A second Ctrl-C interrupts at once.
        """
        with SigintFlag() as flag:
            while not flag.raised and self.step():
                pass
        if flag.raised:
            self.end_reason = "interrupted"
            raise Interrupted(self.result())
        return self.result()

    def result(self) -> EpisodeResult:
        curve = np.array(self.curve)
        grid = self.mapper.grid
        log = self.sim.kinematics()
        metrics = episode_metrics(curve, log, iou(grid, self.reference),
                                  self.sim.collisions, self.end_reason or "running")
        metrics["exploration_ratio_check"] = round(
            exploration_ratio(self._seen.grid, self.reference), 5)
        metrics["localization"] = self.config.localization
        positions = np.array(self._positions, np.float64).reshape(-1, 4)
        metrics.update(pose_errors(positions[:, :2], positions[:, 2:]))
        metrics["decisions"] = len(self.goals)
        metrics["fallbacks"] = self.fallbacks
        metrics["reoffers"] = self.reoffers
        metrics["given_up"] = self.blacklist.reasons()
        sha = getattr(self.explorer, "weights_sha256", None)  # A learned explorer's weights.
        if sha is not None:
            metrics["policy"] = cast(Any, self.explorer).policy_name
            metrics["weights_sha256"] = sha
        return EpisodeResult(metrics, curve, log,
                             GridMap(grid.data.copy(), grid.resolution, grid.origin),
                             np.array(self.goals).reshape(-1, 3))
