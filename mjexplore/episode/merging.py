"""Unknown start poses: each robot maps in a frame of its own until its map is merged.

With ``TeamConfig.unknown_starts`` the robots do not know where they started relative to
each other. Each robot maps in a frame of its own (its start pose is the frame's origin)
and explores alone on its own map, its explorer seeing a team of one, until its map
overlaps the team's enough to be merged by matching
(:func:`~mjexplore.mapping.map_merging.merge_maps`: robot ``j``'s own-frame map, grown from
its scans at its poses relative to its start, placed in the team's map). The team's map is
robot 0's: its frame is robot 0's start, drawn in the ground truth's grid at robot 0's true
start pose (a fixed change of coordinates, as an evaluator aligns a robot's map to the
ground truth; it tells the robots nothing). Likewise, before its merge a robot's own map is
drawn in the ground truth's grid through its own start pose, so that the mapping and
planning machinery is the shared map's.

A match counts once a second one, ``merge_period`` seconds later, agrees with it (within
``merge_agreement``); then the robot's scans so far are mapped into the team's map at the
poses the estimate of its start gives, the robot plans on the team's map from then on, its
pose in it being its own-frame pose composed with the estimate, and the team's coordination
takes it in. Each later scan of the robot is aligned to the team's map by a scan match
before it is mapped (``merge_align``), and may not turn the team's wall cells free
(``merge_keep_walls``): the estimate's residual error, a few hundredths of a degree, would
otherwise draw the walls a second time a cell off and punch holes into them, phantom
frontiers (on the office, enough to double the team's time). The merge's error is the
estimated start pose against the true one (metres and degrees, in ``merges`` of the
metrics). The team's exploration ratio is that of the union of the robots' maps until all
have merged, then that of the team's map. Robots see each other before they merge (their
lidars do), so their bodies are obstacles in each other's costmaps throughout.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mjexplore.episode.metrics import KnownCounter
from mjexplore.episode.team import Team, TeamConfig
from mjexplore.mapping.map_merging import merge_maps
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.mapping.scan_matching import match_scan, scan_points
from mjexplore.maps import OCCUPIED, GridMap
from mjexplore.navigation.navigator import NavStatus
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.odometry import compose_pose, relative_pose, wrap_angle
from mjexplore.topology.pipeline import TopologyConfig, TopologyTracker


class MapMerging:
    """The merging part of a team episode whose robots do not know their relative starts.

    Args:
        team: The team (whose ``members`` says who shares the team's map).
        ground_truth: The scene's map.
        reference: Its observable part.
        starts: The robots' true start poses.
        topology: Frontier and GVD settings (each unmerged robot has a GVD of its own).
    """

    def __init__(self, team: Team, ground_truth: GridMap, reference: GridMap, starts: list,
                 topology: TopologyConfig) -> None:
        n = len(starts)
        self.team = team
        self.config: TeamConfig = team.config
        self.starts = starts
        team.members = [True] + [False] * (n - 1)
        self.merges: list[dict[str, Any]] = []
        self.attempts = 0
        self.aligned_scans = 0
        self.kept_walls = 0
        self._trackers: list[TopologyTracker | None] = [None] * n
        self._frames: list[OccupancyMapper | None] = [None] * n
        self._history: list[list[LaserScan]] = [[] for _ in range(n)]
        self._candidates: list[np.ndarray | None] = [None] * n
        self._next_attempt = [0.0] * n
        res = MapperConfig(resolution=ground_truth.resolution)
        self.union = OccupancyMapper.like(ground_truth, res)
        self.union_counter = KnownCounter(reference)
        w, h = ground_truth.size_m
        centre = np.array([ground_truth.origin[0] + w / 2, ground_truth.origin[1] + h / 2, 0.0])
        half = 0.5 * math.hypot(w, h) + 1.0
        cells = int(math.ceil(2 * half / ground_truth.resolution))
        for j in range(1, n):
            self._trackers[j] = TopologyTracker(ground_truth.shape, topology, ground_truth)
            # The own-frame map: a square that holds the building in any orientation (its
            # size and placement are memory only; nothing of them reaches the matcher).
            c = relative_pose(starts[j], centre)
            self._frames[j] = OccupancyMapper((cells, cells), (c[0] - half, c[1] - half), res)

    @property
    def merged(self) -> list[bool]:
        """Which robots plan on the team's map."""
        return self.team.members

    @property
    def all_merged(self) -> bool:
        return all(self.merged)

    def own_tracker(self, index: int) -> TopologyTracker:
        """The GVD and frontiers of unmerged robot ``index``'s own map."""
        tracker = self._trackers[index]
        assert tracker is not None  # Every unmerged robot has its own.
        return tracker

    # ------------------------------------------------------------------ mapping

    def integrate_merged(self, mapper: OccupancyMapper, agent: Any,
                         scan: LaserScan) -> np.ndarray:
        """Maps a merged robot's scan into the team's map (``mapper``); returns the changed
        cells. A robot placed by a merge estimate (``merge_keep_walls``) may not turn the
        team's wall cells free: its residual error would punch holes into them."""
        pose = self._merged_pose(mapper, agent, scan)
        if pose is None or not self.config.merge_keep_walls:
            return mapper.integrate(scan, pose)
        state = mapper.state.reshape(-1)
        logodds = mapper.logodds.reshape(-1)
        walls = np.flatnonzero(state == OCCUPIED)
        saved = logodds[walls]
        changed = mapper.integrate(scan, pose)
        lost = state[walls] != OCCUPIED
        if not lost.any():
            return changed
        logodds[walls[lost]] = saved[lost]
        state[walls[lost]] = OCCUPIED
        self.kept_walls += int(lost.sum())
        cols = mapper.state.shape[1]
        return changed[~np.isin(changed[:, 0] * cols + changed[:, 1], walls[lost])]

    def _merged_pose(self, mapper: OccupancyMapper, agent: Any,
                     scan: LaserScan) -> np.ndarray | None:
        """Where a merged robot's scan goes into the team's map: None (its pose) for robot
        0, else where the merge's estimate puts it, aligned to the map by a scan match
        (``merge_align``) when one is accepted."""
        if agent.correction is None:
            return None
        prior = compose_pose(agent.correction, scan.pose)
        cfg = self.config.merge_align
        if cfg is None:
            return prior
        match = match_scan(scan_points(scan), mapper.grid, prior, cfg)
        self.aligned_scans += match.accepted
        return match.pose if match.accepted else prior

    def keep(self, index: int, scan: LaserScan) -> None:
        """Maps an unmerged robot's scan into its own-frame map and keeps it for the merge."""
        frame = self._frames[index]
        assert frame is not None  # Set for every unmerged robot.
        frame.integrate(scan, relative_pose(self.starts[index], scan.pose))
        self._history[index].append(scan)

    def unite(self, scan: LaserScan) -> float:
        """Maps ``scan`` into the union of the robots' maps; its exploration ratio."""
        changed = self.union.integrate(scan)
        return self.union_counter.update(self.union.state, changed, self.union.grid.shape[1])

    # ------------------------------------------------------------------ merging

    def try_merges(self, episode: Any) -> None:
        """Matches each unmerged robot's own-frame map against the team's map once every
        ``merge_period``; merges it when two successive accepted matches agree."""
        t = episode.time
        tc = self.config
        for j in range(len(self.merged)):
            if self.merged[j] or t < self._next_attempt[j]:
                continue
            self._next_attempt[j] = t + tc.merge_period
            self.attempts += 1
            frame = self._frames[j]
            assert frame is not None  # Set for every unmerged robot.
            match = merge_maps(episode.mapper.grid, frame.grid, tc.merge)
            previous, self._candidates[j] = self._candidates[j], None
            if not match.accepted:
                continue
            self._candidates[j] = match.pose
            if previous is not None:
                d = relative_pose(previous, match.pose)
                if math.hypot(d[0], d[1]) <= tc.merge_agreement[0] and \
                        abs(d[2]) <= tc.merge_agreement[1]:
                    self._merge(episode, j, match)

    def _merge(self, episode: Any, j: int, match: Any) -> None:
        """Merges robot ``j``'s map into the team's with ``match``'s pose of its start."""
        estimate = np.asarray(match.pose, float)
        truth = np.asarray(self.starts[j], float)
        agent = episode.agents[j]
        # The correction takes j's true pose to its pose in the team's map: the estimated
        # start composed with its pose relative to its true start.
        correction = compose_pose(estimate, relative_pose(truth, np.zeros(3)))
        agent.correction = correction
        self.merged[j] = True
        mapper = episode.mapper
        changed = [mapper.integrate(scan, compose_pose(correction, scan.pose))
                   for scan in self._history[j]]
        self._history[j] = []
        self._frames[j] = None
        self._trackers[j] = None
        self._candidates[j] = None
        cells = np.unique(np.concatenate(changed), axis=0) if changed else \
            np.zeros((0, 2), np.int64)
        agent.use_map(mapper, episode.tracker, episode.counter)
        episode.observe(mapper, episode.tracker, cells)
        ratio = episode.counter.update(mapper.state, cells, mapper.grid.shape[1])
        episode.set_bodies()
        # Its plans were on its own map: it decides anew on the team's.
        agent.goal = None
        agent.navigator.status = NavStatus.IDLE
        agent._decision_due = True
        agent.end_wait(episode.time)
        if agent.idle_until is not None:
            agent.idle_until = episode.time
        error = relative_pose(truth, estimate)
        self.merges.append({
            "robot": j, "time_s": round(episode.time, 3),
            "error_m": round(float(math.hypot(estimate[0] - truth[0],
                                              estimate[1] - truth[1])), 4),
            "error_deg": round(math.degrees(abs(wrap_angle(float(error[2])))), 4),
            "estimate": [round(float(v), 4) for v in estimate],
            "inliers": round(match.inliers, 4), "conflict": round(match.conflict, 5),
            "wall_overlap_m": round(match.wall_overlap, 2)})
        if self.all_merged:  # From now on the team's ratio is its map's.
            episode.curve.append((episode.time, ratio))

    def metrics(self, counter: KnownCounter) -> dict[str, Any]:
        """The merge's figures for the team's metrics (``counter``: the team map's)."""
        errors = [(m["error_m"], m["error_deg"]) for m in self.merges]
        return {
            "unknown_starts": True,
            "merged": self.all_merged,
            "merge_time_s": self.merges[-1]["time_s"] if self.all_merged else None,
            "merge_error_m": max(e[0] for e in errors) if errors else None,
            "merge_error_deg": max(e[1] for e in errors) if errors else None,
            "merge_attempts": self.attempts,
            "aligned_scans": self.aligned_scans,
            "kept_walls": self.kept_walls,
            "merges": self.merges,
            # The team's map against the ground truth (the union's until all merged).
            "team_map_ratio": round(counter.count / counter.total, 5),
        }


__all__ = ["MapMerging"]
