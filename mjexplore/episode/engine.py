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
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any, cast

import numpy as np

from mjexplore.episode.agent import RobotAgent
from mjexplore.episode.bodies import MovingBodies
from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.episode.merging import MapMerging
from mjexplore.episode.metrics import (
    KnownCounter,
    episode_metrics,
    people_metrics,
    pose_errors,
    team_result,
)
from mjexplore.episode.team import Team, TeamConfig
from mjexplore.errors import UserInputError
from mjexplore.mapping.metrics import exploration_ratio, iou, observable_ground_truth
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.maps import GridMap
from mjexplore.navigation.blacklist import BlacklistConfig, GoalBlacklist
from mjexplore.navigation.navigator import Navigator, NavigatorConfig
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.scenes.scene import SceneFiles, check_start
from mjexplore.scenes.team import check_starts, draw_starts
from mjexplore.sim.kinematics import KinematicsLog
from mjexplore.sim.simulator import SimConfig
from mjexplore.sim.world import make_world
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


class Episode:
    """Runs one episode of one robot or a team; steps are exposed so that callers (logging,
    video, the environments) can watch.

    One robot (one explorer) runs in the scene's world as it is; N > 1 robots (N
    explorers) run in one world holding N robot bodies, share one map and coordinate as
    :mod:`mjexplore.episode.team` says (with unknown relative starts, as
    :mod:`mjexplore.episode.merging` says). Each robot is a
    :class:`~mjexplore.episode.agent.RobotAgent` in ``agents``; with one robot, the agent's
    state reads through the episode too (``pose``, ``goal``, ``navigator``, ...).

    Args:
        scene: The scene.
        explorer: The explorer, or one explorer per robot (a coordinated team's share a
            coordinator).
        seed: Seed for the start jitter (and a team's start poses), sensor noise and the
            explorers.
        config: Episode settings.
        observer: Optional object with any of the hooks ``on_scan(agent, scan)``,
            ``on_decision(agent, state)`` (a robot's new goal) and ``on_step(episode)``;
            ``agent`` is the robot's :class:`~mjexplore.episode.agent.RobotAgent` (its
            ``episode``, ``index``, ``sim``, ``mapper``, ``goal``, ...).
        starts: A team's start poses, one per robot; None: robot 0 where a single robot's
            episode of this seed starts, the others drawn around it
            (:func:`~mjexplore.scenes.team.draw_starts`).
        team_config: Team settings (a team only).
    """

    def __init__(self, scene: SceneFiles, explorer: Explorer | Sequence[Explorer], seed: int,
                 config: EpisodeConfig | None = None, observer: Any = None, *,
                 starts: list | None = None, team_config: TeamConfig | None = None) -> None:
        if scene.ground_truth is None:
            raise ValueError("episodes need a scene with a ground-truth map")
        explorers: list[Explorer] = list(explorer) if isinstance(explorer, (list, tuple)) \
            else [cast(Explorer, explorer)]
        if not explorers:
            raise UserInputError("a team needs at least one robot.")
        self.config = config or EpisodeConfig()
        cfg = self.config
        self.scene = scene
        self.observer = observer
        gt = scene.ground_truth
        n = len(explorers)
        first = self._jittered_start(scene, gt, np.random.default_rng(seed))
        tc = self.team_config = team_config or TeamConfig()
        if n > 1:
            if tc.unknown_starts and cfg.localization != "ground_truth":
                raise UserInputError("unknown starts are merged on ground-truth poses: use "
                                     "--localization ground_truth with --unknown-starts.")
            if tc.unknown_starts and any(getattr(e, "plans_on_ground_truth", False)
                                         for e in explorers):
                raise UserInputError("an explorer that plans on the ground truth knows where "
                                     "the robots are: drop --unknown-starts or choose another.")
        if starts is not None and len(starts) != n:
            raise UserInputError(f"{len(starts)} start poses for {n} robots: give one per "
                                 "robot.")
        if starts is not None:
            starts = [tuple(float(v) for v in p) for p in starts]
            check_starts(gt, starts)
        elif n > 1:
            starts = draw_starts(gt, first, n, np.random.default_rng([seed, n]))
            check_starts(gt, starts)
        else:
            starts = [first]
        self.starts: list[tuple[float, float, float]] = starts
        sim_cfg = dataclasses.replace(cfg.sim, seed=seed)
        if n == 1:
            self.world: Any = make_world(scene, sim_cfg)
            self.world.reset(starts[0])
            robots = [self.world]
        else:
            self.world = make_world(scene, sim_cfg, starts)
            robots = list(self.world.robots)
        self.sim = self.world
        self.crowd = getattr(self.world, "crowd", None)
        self.mapper = OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        # Without ground-truth localisation the robots map where they believe they are, and
        # a second mapper maps the same scans where they were taken: what was really seen.
        self._seen = self.mapper if cfg.localization == "ground_truth" else \
            OccupancyMapper.like(gt, MapperConfig(resolution=gt.resolution))
        self.tracker = TopologyTracker(gt.shape, cfg.topology, gt)
        self.reference = observable_ground_truth(gt)
        self.counter = KnownCounter(self.reference)
        self.curve: list[tuple[float, float]] = []
        self.team: Team | None = None
        self.merging: MapMerging | None = None
        if n > 1:
            self.team = Team(tc, gt, self.reference, n)
            if tc.unknown_starts:
                self.merging = MapMerging(self.team, gt, self.reference, starts, cfg.topology)
        self.agents = [RobotAgent(self, i, robot, e, np.random.default_rng([seed, i]) if i
                                  else np.random.default_rng(seed))
                       for i, (robot, e) in enumerate(zip(robots, explorers))]
        if self.team is not None:
            self.team.agents = self.agents
        self.bodies = None if self.team is None and self.crowd is None else \
            MovingBodies(self.agents, self.crowd, tc.mask_teammates)
        self.end_reason: str | None = None
        for i, robot in enumerate(robots):
            self._integrate(i, robot.latest_scan)

    def _jittered_start(self, scene: SceneFiles, gt: GridMap,
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

    def map_of(self, index: int) -> tuple[OccupancyMapper, TopologyTracker, KnownCounter]:
        """The map robot ``index`` plans on now: the episode's, or before its merge with
        unknown starts its own."""
        if self.merging is None or self.merging.merged[index]:
            return self.mapper, self.tracker, self.counter
        assert self.team is not None  # Merging is a team's.
        return (self.team.own[index], self.merging.own_tracker(index),
                self.team.own_counters[index])

    # ------------------------------------------------------------------ one robot's state

    @property
    def agent(self) -> RobotAgent:
        """The robot of a one-robot episode (robot 0 of a team)."""
        return self.agents[0]

    @property
    def explorer(self) -> Explorer:
        return self.agent.explorer

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of robot 0's ``base_link`` in ``map`` as it believes it (see
        :attr:`RobotAgent.pose`)."""
        return self.agent.pose

    @property
    def navigator(self) -> Navigator:
        return self.agent.navigator

    @property
    def localizer(self) -> Any:
        return self.agent.localizer

    @property
    def goal(self) -> np.ndarray | None:
        return self.agent.goal

    @property
    def goals(self) -> list[tuple[float, float, float]]:
        return self.agent.goals

    @property
    def visited(self) -> list[np.ndarray]:
        return self.agent.visited

    @property
    def blacklist(self) -> GoalBlacklist:
        return self.agent.blacklist

    def costmap(self) -> Costmap:
        return self.agent.costmap()

    def decision_state(self) -> ExplorationState:
        return self.agent.decision_state()

    def adopt_goal(self, goal: np.ndarray, state: ExplorationState | None = None) -> bool:
        return self.agent.adopt_goal(goal, state)

    def decide_fallback(self) -> bool:
        return self.agent.decide_fallback()

    def decision_due(self) -> bool:
        return self.agent.decision_due()

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.world.time

    @property
    def ratio(self) -> float:
        """The exploration ratio now."""
        return self.curve[-1][1] if self.curve else 0.0

    # ------------------------------------------------------------------ mapping

    def _body_centres(self) -> np.ndarray:
        return np.array([r.body_centre for r in self.world.robots])

    def set_bodies(self) -> None:
        """Puts the moving bodies each robot knows into its costmap where they stand now."""
        if self.bodies is not None:
            self.bodies.set_costmaps(self._body_centres())

    def observe(self, mapper: OccupancyMapper, tracker: TopologyTracker,
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
                # An explorer that drives on a costmap of its own over the map (the
                # prediction-driving ones) hears of the cells mapped.
                if hasattr(a.explorer, "map_changed"):
                    a.explorer.map_changed(grid, cells, tracker.gvd.distance2)

    def _integrate(self, index: int, scan) -> None:
        """Maps robot ``index``'s scan."""
        if self.world.physics_fault:
            return  # A broken state would map garbage; the episode ends at the next check.
        agent = self.agents[index]
        team, merging = self.team, self.merging
        # What was seen: every beam from where it was really cast (the LDS-01's are spread
        # over its rotation), less the returns from teammates and people.
        true_scan = agent.deskewed(scan, slice(5, 8))
        logged = scan
        if self.bodies is not None:
            true_scan = logged = self.bodies.mask(index, true_scan, self._body_centres())
        if team is not None:
            own_changed = team.cover(index, true_scan)
        ratio = 0.0
        if merging is not None and not merging.merged[index]:
            # Its own map (its coverage map), and its own-frame map for the merge.
            assert team is not None
            self.observe(team.own[index], merging.own_tracker(index), own_changed)
            merging.keep(index, true_scan)
        else:
            seen = None
            if agent.localizer is not None:
                seen = self._seen.integrate(true_scan)
                logged, sensor_pose = agent.localize(scan)
                if self.bodies is not None:  # The bodies' returns are left out as seen.
                    logged = dataclasses.replace(logged, ranges=np.where(
                        np.isnan(true_scan.ranges), np.nan, logged.ranges))
                changed = self.mapper.integrate(logged, sensor_pose)
            elif merging is not None:
                changed = merging.integrate_merged(self.mapper, agent, true_scan)
            else:
                changed = self.mapper.integrate(true_scan)
            self.observe(self.mapper, self.tracker, changed)
            ratio = self.counter.update(self._seen.state, changed if seen is None else seen,
                                        self.mapper.grid.shape[1])
        if merging is not None:
            union_ratio = merging.unite(true_scan)
            if not merging.all_merged:
                ratio = union_ratio
        self.curve.append((scan.stamp, ratio))
        if self.observer is not None and hasattr(self.observer, "on_scan"):
            self.observer.on_scan(agent, logged)

    def _decision_scan(self, agent: RobotAgent) -> bool:
        """Maps the scan that a world scanning by travel (the grid world's ``scan_travel``)
        skipped at this instant, so that each decision sees the map from where the robot
        stands; True if the episode ended with it."""
        scan = agent.sim.scan_now()
        if scan is None:
            return False
        self._integrate(agent.index, scan)
        return self._check_end()

    # ------------------------------------------------------------------ stepping

    def _check_end(self) -> bool:
        """Sets ``end_reason`` if the episode is over; True then. (The robots' own ends,
        lingering and finding nothing to explore, are :meth:`_retire_lingerers`' and
        :meth:`_all_idle`'.)"""
        if self.end_reason is not None:
            return True
        cfg = self.config
        world = self.world
        if self.ratio >= cfg.target_ratio:
            self.end_reason = "explored"
        elif self.time >= cfg.max_time - 1e-9:
            self.end_reason = "time_limit"
        elif world.physics_fault:
            self.end_reason = "physics_fault"
        elif not all(a.sim.is_upright for a in self.agents):
            self.end_reason = "tipped_over"
        elif all(a.retired is not None for a in self.agents):
            self.end_reason = "lingering"
        return self.end_reason is not None

    def _retire_lingerers(self) -> bool:
        """Stops every exploring robot that lingered through ``linger_strikes`` goals
        (the others go on); True if the episode ended so."""
        for a in self.agents:
            if a.retired is None and a.active and a._yield_goal is None and a.lingered():
                a.retire("lingering")
        return self._check_end()

    def _decide(self, agent: RobotAgent) -> None:
        """Runs ``agent``'s decision if one is due; idles it when it finds nothing."""
        t = self.time
        idle_until = agent.idle_until
        resumed = idle_until is not None
        if idle_until is not None:
            if t < idle_until:
                return
            agent.idle_until = None
            agent._decision_due = True
        if agent.decision_due():
            if self._decision_scan(agent):
                return
            if not agent.decide():
                among = self.bodies is not None
                agent.idle(t, resumed, self.team_config.idle_retry if among else math.inf)
                return
        if resumed:
            agent.idle_time += t - agent.idle_since
            agent.navigator.restart_linger_clock(agent.pose, t)

    def _all_idle(self) -> bool:
        """True when no robot explores and one at least is idle: each finds nothing (a
        team's asked once more now) or has retired."""
        if any(a.active for a in self.agents) or all(a.retired for a in self.agents):
            return False
        if self.bodies is not None:
            for a in self.agents:
                if a.retired is None:
                    a.idle_until = self.time  # Due now: ask again.
                    self._decide(a)
        if self.crowd is not None and any(  # People in the way will move on: wait for them.
                a.retired is None and a.idle_until is not None and
                self.time - a.idle_since < self.team_config.wait_timeout and
                a.frontiers_behind_bodies() for a in self.agents):
            return False
        return not any(a.active for a in self.agents)

    def step(self) -> bool:
        """One control period for every robot; False once the episode has ended."""
        if self._check_end() or self._retire_lingerers():
            return False
        self.set_bodies()
        for a in self.agents:
            if a.retired is None:
                self._decide(a)
        if self._check_end():
            return False
        if self._all_idle():
            self.end_reason = "lost" if any(a.lost() for a in self.agents) else "no_frontiers"
            return False
        if self.team is not None:
            self.team.resolve_blocks(self.time, self.world.poses())
        self.control()
        return True

    def control(self) -> None:
        """One control period of navigation: each robot drives towards its goal (a robot
        that stands idle or retired stands still), the world steps and the scans are
        mapped."""
        poses = []
        for a in self.agents:
            if a.active or a._yield_goal is not None:
                poses.append(a.command())
            else:
                a.sim.command(0.0, 0.0)
                poses.append(a.pose)
        dt = 1.0 / self.config.control_rate_hz
        if self.team is None:
            for scan in self.world.step(dt):
                self._integrate(0, scan)
        else:
            scans = self.world.step_all(dt)
            for k in range(max((len(s) for s in scans), default=0)):
                for i, robot_scans in enumerate(scans):
                    if k < len(robot_scans):
                        self._integrate(i, robot_scans[k])
        for a, pose in zip(self.agents, poses):
            a.record_visit(pose)
        if self.merging is not None and not self.merging.all_merged:
            self.merging.try_merges(self)
        if self.observer is not None and hasattr(self.observer, "on_step"):
            self.observer.on_step(self)

    def run_to_decision(self) -> bool:
        """Runs control periods until robot 0's decision is due (True) or the episode ends
        (False); for callers that choose its goals themselves (the Gymnasium env)."""
        while not (self._check_end() or self._retire_lingerers()):
            if self.agent.decision_due():
                return not self._decision_scan(self.agent)
            self.control()
        return False

    def run(self) -> Any:
        """Steps to the end.

        Ctrl-C (SIGINT) is taken between control periods (never inside MuJoCo or numba
        code): the episode ends as ``interrupted`` and :class:`Interrupted`, carrying the
        result so far, is raised. A second Ctrl-C interrupts at once.

        Returns:
            :meth:`result`.
        """
        with SigintFlag() as flag:
            while not flag.raised and self.step():
                pass
        if flag.raised:
            self.end_reason = "interrupted"
            raise Interrupted(self.result())
        return self.result()

    def result(self) -> Any:
        """What the episode produced: an :class:`EpisodeResult` for one robot, a
        :class:`~mjexplore.episode.metrics.TeamEpisodeResult` for a team."""
        if self.team is not None:
            return team_result(self)
        agent = self.agent
        curve = np.array(self.curve)
        grid = self.mapper.grid
        log = self.world.kinematics()
        metrics = episode_metrics(curve, log, iou(grid, self.reference),
                                  self.world.collisions, self.end_reason or "running")
        metrics["exploration_ratio_check"] = round(
            exploration_ratio(self._seen.grid, self.reference), 5)
        metrics["localization"] = self.config.localization
        positions = np.array(agent._positions, np.float64).reshape(-1, 4)
        metrics.update(pose_errors(positions[:, :2], positions[:, 2:]))
        metrics["decisions"] = len(agent.goals)
        metrics["fallbacks"] = agent.fallbacks
        metrics["reoffers"] = agent.reoffers
        metrics["given_up"] = agent.blacklist.reasons()
        sha = getattr(agent.explorer, "weights_sha256", None)  # A learned explorer's weights.
        if sha is not None:
            metrics["policy"] = cast(Any, agent.explorer).policy_name
            metrics["weights_sha256"] = sha
        crowd = getattr(self.world, "crowd", None)
        if crowd is not None:
            metrics.update(people_metrics(self.world, crowd, log))
        return EpisodeResult(metrics, curve, log,
                             GridMap(grid.data.copy(), grid.resolution, grid.origin),
                             np.array(agent.goals).reshape(-1, 3))


__all__ = ["END_REASONS", "LOCALIZATIONS", "Episode", "EpisodeConfig", "EpisodeResult",
           "Interrupted", "SigintFlag"]
