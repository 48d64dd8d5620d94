"""One robot of an episode: its explorer, navigator, costmap, blacklist, localiser and clocks.

An :class:`~mjexplore.episode.engine.Episode` runs one :class:`RobotAgent` per robot of its
world, alone or in a team; the map, the end rules and the metrics are the episode's. The
agent asks its explorer for goals, adopts them, drives to them and gives them up (no path,
no progress, lingering, standing at a frontier that stays open); when its explorer has
nothing left it falls back to the nearest reachable frontier, offering given-up goals
again. What only a robot among moving bodies or a teammate does is here too, inert for a
robot alone: waiting while only teammates or people keep a goal out of reach
(:mod:`mjexplore.episode.bodies`), standing idle with nothing to explore, stopping for good
after lingering, and driving aside for another robot (:mod:`mjexplore.episode.team`).
"""

from __future__ import annotations

import math
from typing import Any, cast

import cv2
import numpy as np

from mjexplore.episode.explorer import ExplorationState, Explorer
from mjexplore.episode.metrics import KnownCounter
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.errors import UserInputError
from mjexplore.mapping.localization import FusedLocalizer, LocalizerConfig
from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.mapping.scan_matching import ScanMatchingLocalizer, deskew_scan
from mjexplore.navigation.blacklist import GoalBlacklist
from mjexplore.navigation.bodies import BodyCostmap
from mjexplore.navigation.navigator import Navigator, NavStatus
from mjexplore.navigation.planner import Costmap
from mjexplore.navigation.safety import safe_command
from mjexplore.sim.motion import BODY_RADIUS
from mjexplore.sim.odometry import compose_pose
from mjexplore.topology.frontiers import frontier_mask
from mjexplore.topology.pipeline import TopologyTracker


class RobotAgent:
    """One robot's decisions and navigation in an episode.

    Args:
        episode: The :class:`~mjexplore.episode.engine.Episode` (its map, settings,
            observer and team, if any).
        index: The robot's number in the world.
        sim: The robot in the world (pose, odometry, lidar, commands, kinematics log).
        explorer: Its explorer.
        rng: The explorer's random generator.
    """

    def __init__(self, episode: Any, index: int, sim: Any, explorer: Explorer,
                 rng: np.random.Generator) -> None:
        cfg = episode.config
        self.episode = episode
        self.index = index
        self.config = cfg
        self.scene = episode.scene
        self.explorer = explorer
        self.sim = sim
        # Where the robot believes it is; None: it knows (ground-truth localisation).
        self.localizer: ScanMatchingLocalizer | FusedLocalizer | None = None
        if cfg.localization == "scan_matching":
            self.localizer = FusedLocalizer(
                sim.pose, odom_pose=sim.odom_pose,
                config=LocalizerConfig.for_lidar(sim.lidar.config, cfg.sim.odometry_heading))
        elif cfg.localization != "ground_truth":
            self.localizer = ScanMatchingLocalizer(sim.pose, odom_pose=sim.odom_pose)
        # Where a merge of unknown starts placed the robot's frame in the team's map (the
        # transform from its true pose to its pose there); None: the frames agree.
        self.correction: np.ndarray | None = None
        self._positions: list[tuple[float, float, float, float]] = []  # Estimate, truth.
        self.navigator = Navigator(sim.profile, cfg.navigator)
        self.curve = episode.curve
        self._static_costmap: Costmap | None = None
        self.use_map(*episode.map_of(index))
        explorer.reset(rng)
        self._start_deciding()
        self.goals: list[tuple[float, float, float]] = []
        self.visited: list[np.ndarray] = []
        # Team state (never set for a robot alone: it ends the episode instead).
        self.retired: str | None = None  # Why the robot stopped for good ('lingering').
        self.idle_until: float | None = None  # Next retry, while it finds nothing to do.
        self.idle_since = 0.0
        self.idle_time = 0.0
        self.waiting_since: float | None = None  # Set while bodies block its goal.
        self._retry_at = 0.0
        self.waits = 0
        self.wait_time = 0.0
        self.yields = 0
        self._yield_goal: np.ndarray | None = None
        self._blocked_since: float | None = None

    def use_map(self, mapper: OccupancyMapper, tracker: TopologyTracker,
                counter: KnownCounter) -> None:
        """Plans on ``mapper``'s map (with ``tracker``'s GVD and frontiers) from now on: a
        costmap of its own over it, with the moving bodies it knows in it (teammates,
        people). An explorer with a ``driving_costmap(grid)`` of its own drives on that
        (alone, without people).

        Raises:
            UserInputError: such an explorer in a team or among people."""
        self.mapper = mapper
        self.tracker = tracker
        self.counter = counter
        cfg = self.config
        team, crowd = self.episode.team, self.episode.crowd
        drives_own = hasattr(self.explorer, "driving_costmap")
        if drives_own and (team is not None or crowd is not None):
            raise UserInputError(f"{self.explorer.name} drives on a costmap of its own, "
                                 "without moving bodies in it: run it alone, without "
                                 "--robots or --people.")
        knows_truth = getattr(self.explorer, "plans_on_ground_truth", False)
        # A robot alone plans on the map; among moving bodies on the map with them in it. An
        # explorer that knows the ground truth also navigates on it (alone or among people:
        # without them in it; in a team: with the teammates in it).
        if team is None and (crowd is None or knows_truth):
            self._costmap: Costmap = Costmap(mapper.grid, tracker.gvd.distance2, cfg.planner)
            if drives_own:
                self._static_costmap = cast(Any, self.explorer).driving_costmap(mapper.grid)
            elif knows_truth:
                gt = self.scene.ground_truth
                assert gt is not None  # The episode checked the scene.
                self._static_costmap = cast(Any, self.explorer).ground_truth_costmap(
                    ExplorationState(gt, self.sim.pose, 0.0, [], self._costmap,
                                     np.zeros((0, 2)), ground_truth=gt))
            return
        margin = cfg.planner.lethal_radius + self.episode.team_config.teammate_margin
        radii = {"teammate_radius": BODY_RADIUS + margin,
                 "person_radius": margin + (0.0 if crowd is None else crowd.config.radius)}
        if knows_truth:  # The team oracle: the ground truth, with the teammates in it.
            assert team is not None and self.scene.ground_truth is not None
            self._costmap = BodyCostmap(self.scene.ground_truth, team.ground_truth_distance2(),
                                        cfg.planner, **radii)
        else:
            self._costmap = BodyCostmap(mapper.grid, tracker.gvd.distance2, cfg.planner,
                                        **radii)

    def _start_deciding(self) -> None:
        """The decision and navigation state of a fresh episode: no goal, no blacklist, no
        strikes."""
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

    # ------------------------------------------------------------------ state

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of ``base_link`` in the frame of the map the robot plans on, as the
        robot believes it: the localiser's estimate; with ground-truth localisation the true
        pose, placed by the merge's estimate of its start once merged with unknown starts."""
        if self.localizer is not None:
            return self.localizer.pose
        pose = self.sim.pose
        return pose if self.correction is None else compose_pose(self.correction, pose)

    @property
    def waiting(self) -> bool:
        """Whether teammates or people keep the robot's goal out of reach (it waits)."""
        return self.waiting_since is not None

    @property
    def active(self) -> bool:
        """Whether the robot explores (it has not stopped for good and is not idle)."""
        return self.retired is None and self.idle_until is None

    def costmap(self) -> Costmap:
        """The planner's costmap (kept current as scans arrive)."""
        return self._static_costmap or self._costmap

    def decision_state(self) -> ExplorationState:
        """What the explorer sees now (frontiers already filtered by the blacklist; in a
        team, ``extras['team']`` holds the team's :class:`~mjexplore.episode.team.TeamView`)."""
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
        if self.episode.team is not None:
            state.extras["team"] = self.episode.team.view(self.index)
        frontiers = self.tracker.frontiers(grid)
        if frontiers:
            allowed = state.allowed([f.goal for f in frontiers])
            state.frontiers = [f for f, ok in zip(frontiers, allowed) if ok]
        return state

    # ------------------------------------------------------------------ sensing

    def deskewed(self, scan, columns: slice):
        """The scan as if all its beams were cast from ``base_scan`` at its stamp, undone
        along the base's trajectory in ``kinematics_rows[:, columns]`` (5:8 the true poses,
        8:11 the odometry's); the scan itself when its beams were cast at once."""
        rows = self.sim.kinematics_rows
        if scan.time_increment == 0 or len(rows) < 2:
            return scan
        first = scan.stamp + min(scan.time_increment * (len(scan.ranges) - 1), 0.0)
        lo = max(int(np.searchsorted(rows[:, 0], first)) - 1, 0)
        return deskew_scan(scan, trajectory=(rows[lo:, 0], rows[lo:, columns]))

    def localize(self, scan):
        """Updates the pose estimate to the scan's stamp; the scan as the robot maps it
        (deskewed when its beams were taken over time) and its sensor pose."""
        loc = self.localizer
        assert loc is not None  # Asked only of a robot with a localiser.
        rows = self.sim.kinematics_rows
        if len(rows) == 0:
            odom, truth, stamp = self.sim.odom_pose, self.sim.pose, self.sim.time
        else:
            recent = rows[-40:]
            k = int(np.argmin(np.abs(recent[:, 0] - scan.stamp)))  # Scans fall on samples.
            odom, truth, stamp = recent[k, 8:11], recent[k, 5:8], float(recent[k, 0])
        loc.advance(odom, stamp)
        scan = self.deskewed(scan, slice(8, 11))
        if self.config.localization == "scan_matching":
            loc.correct(scan, self.mapper)
        estimate = loc.pose
        self._positions.append((estimate[0], estimate[1], truth[0], truth[1]))
        return scan, loc.sensor_pose

    # ------------------------------------------------------------------ goals

    def goal_still_open(self) -> bool:
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

    def adopt_goal(self, goal: np.ndarray, state: ExplorationState | None = None) -> bool:
        """Makes ``goal`` (x, y, metres) the navigation goal.

        Returns:
            False if the goal was refused: no path leads to it (given up, or in a team
            waited for while only teammates block the way), or it lies within zeta yet its
            frontier is still open (the lidar cannot see it from here).
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
        observer = self.episode.observer
        if observer is not None and hasattr(observer, "on_decision"):
            observer.on_decision(self, state if state is not None else self.decision_state())
        pose = self.pose
        near = np.hypot(*(self.goal - pose[:2])) <= self.config.navigator.goal_tolerance
        if near and not getattr(self.explorer, "waypoint", False) and self.goal_still_open():
            self.give_up("seen_open")
            return False
        if not self.navigator.set_goal(self.goal, self.costmap(), pose, self.sim.time):
            self.give_up("no_path")
            return False
        self._best_distance = self.navigator.remaining_length(pose)
        self._best_time = self._decided_at = self.sim.time
        self._route_restarts = 0
        self._decision_due = False
        return True

    def give_up(self, reason: str) -> None:
        """Blacklists the current goal for ``reason`` and asks for a new one; a goal that
        only moving bodies (teammates, people) keep out of reach is waited for
        (``wait_timeout``) before it is given up."""
        assert self.goal is not None  # Given up only once adopted.
        costmap = self._costmap
        if isinstance(costmap, BodyCostmap) and reason == "no_path" and \
                self._yield_goal is None and costmap.blocked_by_bodies(
                    self.pose[:2], self.goal, self.config.navigator.goal_tolerance):
            t = self.sim.time
            tc = self.episode.team_config
            if self.waiting_since is None:
                self.waiting_since = t
                self.waits += 1
            if t - self.waiting_since < tc.wait_timeout:
                self.navigator.status = NavStatus.NO_PATH
                self._decision_due = True
                self._retry_at = t + tc.retry_period
                return
        self.end_wait(self.sim.time)
        self.blacklist.add(self.goal, reason, self.mapper.grid)
        self.navigator.status = NavStatus.NO_PATH
        self._decision_due = True

    def end_wait(self, t: float) -> None:
        """Stops waiting for moving bodies (if it was), counting the time waited."""
        if self.waiting_since is not None:
            self.wait_time += t - self.waiting_since
            self.waiting_since = None

    def decide(self) -> bool:
        """Asks the explorer for a goal; False when exploration is over for this robot.

        An explorer's "nothing left" is checked against the map (:meth:`decide_fallback`),
        so an explorer that misses small or distant frontiers (one that drops frontiers
        under a size, a coarse view) does not end the episode early. A robot waiting for
        teammates asks again only every ``retry_period`` seconds.
        """
        t = self.sim.time
        if self.waiting_since is not None and t < self._retry_at:
            return True
        for _ in range(8):
            state = self.decision_state()
            goal = self.explorer.select_goal(state)
            if goal is None:
                return self.decide_fallback()
            if self.adopt_goal(goal, state):
                self.end_wait(t)
                return True
            if self.waiting_since is not None:
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

    def drive_aside(self, target: np.ndarray) -> bool:
        """Drives to ``target`` (x, y) out of a teammate's way, deciding again once there
        (or once it makes no progress); False if no path leads there."""
        self.end_wait(self.sim.time)
        if not self.navigator.set_goal(target, self._costmap, self.pose, self.sim.time):
            return False
        self.goal = target
        self._yield_goal = target
        self.goals.append((self.sim.time, *target))
        self.yields += 1
        self._best_distance = self.navigator.remaining_length(self.pose)
        self._best_time = self._decided_at = self.sim.time
        self._decision_due = False
        return True

    # ------------------------------------------------------------------ clocks

    def lingered(self) -> bool:
        """True when the robot has stayed on one spot through ``linger_strikes`` goals;
        before that, a goal the robot lingers on is given up and the clock restarts."""
        pose, t = self.pose, self.sim.time
        radius = self.config.navigator.linger_radius
        if self._strike_at is not None and np.hypot(*(pose[:2] - self._strike_at)) > radius:
            self._linger_strikes, self._strike_at = 0, None
        if not self.navigator.lingering(pose, t):
            return False
        if self.goal is None or self._linger_strikes >= self.config.linger_strikes:
            return True
        self._linger_strikes += 1
        self._strike_at = pose[:2].copy()
        self.give_up("lingered")
        self.navigator.restart_linger_clock(pose, t)
        return False

    def retire(self, reason: str) -> None:
        """Stops the robot for good (``reason``: why)."""
        self.retired = reason
        self.navigator.status = NavStatus.IDLE
        self.goal = None

    def frontiers_behind_bodies(self) -> bool:
        """Whether a frontier that no path reaches now would be reached without the moving
        bodies in the costmap: a way that opens when they move on."""
        costmap = self._costmap
        if not isinstance(costmap, BodyCostmap) or not len(costmap.body_cells):
            return False
        frontiers = self.decision_state().frontiers
        return bool(frontiers) and costmap.reachable_without_bodies(
            self.pose[:2], np.array([f.goal for f in frontiers]))

    def idle(self, t: float, resumed: bool, retry: float) -> None:
        """Stands the robot idle (nothing to explore) until ``t + retry``."""
        self.goal = None
        self.navigator.status = NavStatus.IDLE
        self.end_wait(t)
        if not resumed:
            self.idle_since = t
        self.idle_until = t + retry

    def decision_due(self) -> bool:
        """Whether the explorer must choose a goal before the next control period (the
        goal was reached, vanished, failed or made no progress, the explorer re-plans every
        ``replan_period`` seconds, or the robot is where it drove aside to). Evaluated once
        per control period; stays True until a goal is adopted."""
        cfg = self.config
        pose, t = self.pose, self.sim.time
        if self._yield_goal is not None:
            if self.navigator.status == NavStatus.ACTIVE and \
                    t - self._best_time <= cfg.progress_timeout:
                d = self.navigator.remaining_length(pose)
                if d < self._best_distance - 0.25:
                    self._best_distance, self._best_time = d, t
                return False
            self._yield_goal = None  # Moved aside (or could not): explore on.
            self.goal = None
            self._decision_due = True
            return True
        if self._decision_due:
            return True
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
                self.give_up("no_progress")
                return True
        if self.goal is None or self.navigator.status != NavStatus.ACTIVE or \
                not self.goal_still_open():
            if self.navigator.status == NavStatus.REACHED and self.goal_still_open():
                # Reached, yet still next to unknown space: the lidar cannot see it from
                # here (a blind corner, a gap too small).
                self.give_up("seen_open")
            self._decision_due = True
        return self._decision_due

    # ------------------------------------------------------------------ driving

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
        elif self.episode.crowd is not None:
            v, w = self.clear_of_people(v, w)
        sim.command(v, w)
        return pose

    def clear_of_people(self, v: float, w: float) -> tuple[float, float]:
        """(v, w) slowed or stopped so as not to touch the people the last scan saw
        (:func:`~mjexplore.navigation.safety.safe_command`; in the robot's own frame, as the
        scan gives them: from its true pose, whatever its localiser believes)."""
        bodies = self.episode.bodies
        seen = bodies.seen[self.index] if bodies is not None else ()
        if not len(seen):
            return v, w
        crowd = self.episode.crowd
        return safe_command(self.sim.pose, v, w, crowd.positions[seen],
                            crowd.velocities[seen], crowd.config.radius)

    def record_visit(self, pose: np.ndarray) -> None:
        """Adds ``pose``'s position to ``visited`` once it is 0.25 m from the last one."""
        last = self.visited[-1] if self.visited else None
        if last is None or np.hypot(pose[0] - last[0], pose[1] - last[1]) > 0.25:
            self.visited.append(pose[:2].copy())

    def lost(self) -> bool:
        """True when the robot's estimate has no traversable cell of its map near it (off
        the map, or inside a wall): planning from it fails whatever is left to explore."""
        return (self.localizer is not None and
                self.costmap().nearest_traversable(self.pose[:2]) < 0)


__all__ = ["RobotAgent"]
