"""A team of robots in the grid world: N :class:`~mjexplore.sim.grid_world.GridWorld` robots
on one clock, seeing and blocking each other.

The grid world's robot, N times, stepped together as a team's
:class:`~mjexplore.sim.simulator.Simulator` steps its MuJoCo robots (moves, then samples,
then scans, on the same grids of 0.005 s steps), with what a team adds: each lidar also
sees its teammates' silhouettes (the same boxes the MuJoCo team's lidars see, cast with
:func:`~mjexplore.sim.lidar.ray_boxes`), and a move that would bring a robot's bounding circle
into a teammate's is refused (as in the kinematic world) and counted as a robot-robot
contact. Seeds as in the MuJoCo team: robot 0 draws from the config's seed.
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.scenes.scene import SceneFiles, load_scene_files
from mjexplore.scenes.team import SILHOUETTE_HALF, SILHOUETTE_POS, robot_prefix
from mjexplore.sim.grid_world import GridLidar, GridWorld
from mjexplore.sim.lidar import LaserScan, ray_boxes
from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS
from mjexplore.sim.simulator import COLLISION_GAP_S, SimConfig, Simulator, float_pose, robot_seed

SCAN_HEIGHT = 0.132  # base_scan above the floor, metres (the MJCF's).


class TeamGridLidar(GridLidar):
    """A grid lidar that also sees the teammates' silhouettes.

    Args:
        team: The team (its robots' poses are read at each cast).
        index: The robot carrying the lidar.
        *args, **kwargs: :class:`GridLidar`'s.
    """

    def __init__(self, team: TeamGridWorld, index: int, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._team = team
        self._index = index
        self._half = np.array(SILHOUETTE_HALF)

    def cast(self, x, y, yaw) -> np.ndarray:
        dist = super().cast(x, y, yaw)
        others = [r for r in self._team.robots if r.index != self._index]
        if not others:
            return dist
        # Beams from the scan's origin (under motion skew: the origin of its last beam).
        bx, by, byaw = (float(np.ravel(v)[-1]) for v in (x, y, yaw))
        ox, oy = self._offset
        c, s = math.cos(byaw), math.sin(byaw)
        origin = np.array([bx + c * ox - s * oy, by + s * ox + c * oy, SCAN_HEIGHT])
        heading = np.asarray(yaw) + self._angles
        vec = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(len(heading))])
        centres, rots = [], []
        reach = self.config.range_max + 0.3
        for r in others:
            rx, ry, ryaw = r._pose
            cx = rx + SILHOUETTE_POS[0] * math.cos(ryaw)
            cy = ry + SILHOUETTE_POS[0] * math.sin(ryaw)
            if math.hypot(cx - origin[0], cy - origin[1]) > reach:
                continue
            cr, sr = math.cos(ryaw), math.sin(ryaw)
            centres.append((cx, cy, SCAN_HEIGHT))
            rots.append(((cr, -sr, 0.0), (sr, cr, 0.0), (0.0, 0.0, 1.0)))
        if not centres:
            return dist
        hit, _, normal = ray_boxes(origin, vec, np.array(centres), np.array(rots), self._half)
        nearer = (hit >= 0) & ((dist < 0) | (hit < dist))
        dist[nearer] = hit[nearer]
        self._cos[nearer] = np.abs(np.einsum("ij,ij->i", vec[nearer], normal[nearer]))
        return dist


class TeammateBody:
    """What a robot of a team adds to its world: contacts with teammates count as
    collisions, and its body's bounding circle for the teammates' costmaps and lidars."""

    _in_contact: bool
    _teammate_contact: bool
    _team: TeamGridWorld
    pose: np.ndarray  # The world's (x, y, yaw) of base_link.

    @property
    def in_collision(self) -> bool:
        """Touching a wall or a teammate."""
        return self._in_contact or self._teammate_contact

    @property
    def body_centre(self) -> tuple[float, float]:
        """Centre of the body's bounding circle (radius ``BODY_RADIUS``), ``map`` frame."""
        x, y, yaw = self.pose
        return x + BODY_CENTRE_X * math.cos(yaw), y + BODY_CENTRE_X * math.sin(yaw)

    def _moved_into_teammate(self, centre_before: tuple[float, float]) -> bool:
        """Whether the move just made, from a body centre at ``centre_before``, brought the
        body into a teammate's (bounding circles overlapping, and nearer than before)."""
        after = self.body_centre
        for other in self._team.robots:
            if other is self:
                continue
            ox, oy = other.body_centre
            d = math.hypot(after[0] - ox, after[1] - oy)
            if d < 2 * BODY_RADIUS and d < math.hypot(centre_before[0] - ox,
                                                      centre_before[1] - oy):
                return True
        return False


class TeamGridRobot(TeammateBody, GridWorld):
    """One robot of a :class:`TeamGridWorld`: the grid world's robot; the team steps."""

    _team: TeamGridWorld

    def __init__(self, team: TeamGridWorld, index: int, start) -> None:  # noqa: D107
        self._team = team
        self.index = index
        self.name = robot_prefix(index).rstrip("/")
        config = dataclasses.replace(team.config, seed=robot_seed(team.config.seed, index))
        scene = dataclasses.replace(team.scene, start=float_pose(start))
        super().__init__(scene, config)
        self.lidar = TeamGridLidar(team, index, scene.ground_truth, self.lidar.config, self._rng)
        self.robot_contacts = 0
        self._teammate_contact = False
        self._last_teammate = -math.inf
        self._refused_by_teammate = False

    def _move(self, stop: int) -> None:
        before = self._pose, self._wheels
        centre = self.body_centre
        super()._move(stop)
        self._refused_by_teammate = self._moved_into_teammate(centre)
        if self._refused_by_teammate:
            self._pose, self._wheels = before
            self._twist = (0.0, 0.0)

    def _note_teammate(self, touching: bool) -> None:
        t = self.time
        if touching:
            if t - self._last_teammate > COLLISION_GAP_S:
                self.robot_contacts += 1
            self._last_teammate = t
        self._teammate_contact = touching


class TeamGridWorld:
    """N robots on a scene's ground-truth grid, stepped together (the grid world's team).

    Args and attributes as a team's :class:`~mjexplore.sim.simulator.Simulator`'s.
    """

    def __init__(self, scene: str | os.PathLike | SceneFiles, starts: list,
                 config: SimConfig | None = None) -> None:
        self.config = config or SimConfig(dynamics="grid")
        if self.config.scan_travel is not None:
            raise UserInputError("a team's grid world scans at the lidar's rate: drop "
                                 "scan_travel.")
        self.scene = scene if isinstance(scene, SceneFiles) else load_scene_files(scene)
        if self.scene.ground_truth is None:
            raise UserInputError("the grid world needs the scene's ground-truth map.")
        self.starts = [float_pose(p) for p in starts]
        self.robots: list[TeamGridRobot] = []
        for i, start in enumerate(self.starts):
            self.robots.append(TeamGridRobot(self, i, start))
        self.robot_collisions = 0
        self._pair_last: dict[tuple[int, int], float] = {}
        self.reset()

    def __len__(self) -> int:
        return len(self.robots)

    @property
    def time(self) -> float:
        return self.robots[0].time

    @property
    def physics_fault(self) -> bool:
        return any(r.physics_fault for r in self.robots)

    def warnings(self) -> dict[str, int]:
        return {}

    def poses(self) -> np.ndarray:
        return np.array([r.pose for r in self.robots])

    def reset(self, poses: list | None = None) -> list[LaserScan]:
        """Puts every robot at rest at ``poses`` (default: the starts) at time 0; returns
        each robot's first scan (taken with every robot in place)."""
        poses = self.starts if poses is None else [float_pose(p) for p in poses]
        for r, pose in zip(self.robots, poses):
            r._pose = pose  # Everyone in place before the first scans.
        for r, pose in zip(self.robots, poses):
            r.reset(pose)
            r.robot_contacts = 0
            r._teammate_contact = False
            r._last_teammate = -math.inf
        self.robot_collisions = 0
        self._pair_last = {}
        return [r.latest_scan for r in self.robots]

    def step_all(self, duration: float) -> list[list[LaserScan]]:
        """Advances simulated time by ``duration`` seconds; each robot's scans, oldest
        first."""
        first = self.robots[0]
        end = first._steps + max(0, round(duration / first.timestep))
        sample, scan = first._sample_every, first._scan_every
        scans: list[list[LaserScan]] = [[] for _ in self.robots]
        while first._steps < end:
            stop = min((first._steps // sample + 1) * sample,
                       (first._steps // scan + 1) * scan, end)
            for r in self.robots:
                r._move(stop)
            if stop % sample == 0:
                self._contacts()
                for r in self.robots:
                    r._sample()
                    r._cmd_base = r._cmd
                    r._ramp()
            if stop % scan == 0:
                for r, out in zip(self.robots, scans):
                    out.append(r._take_scan())
        return scans

    def _contacts(self) -> None:
        pairs = set()
        touching = np.zeros(len(self.robots), bool)
        for r in self.robots:
            if not r._refused_by_teammate:
                continue
            cx, cy = r.body_centre
            for o in self.robots:
                ox, oy = o.body_centre
                if o is not r and math.hypot(cx - ox, cy - oy) < 2 * BODY_RADIUS + 0.01:
                    touching[[r.index, o.index]] = True
                    pairs.add((min(r.index, o.index), max(r.index, o.index)))
        for r in self.robots:
            r._note_teammate(bool(touching[r.index]))
        t = self.time
        for pair in pairs:
            if t - self._pair_last.get(pair, -math.inf) > COLLISION_GAP_S:
                self.robot_collisions += 1
            self._pair_last[pair] = t


def make_team_world(scene: str | os.PathLike | SceneFiles, starts: list,
                    config: SimConfig | None = None) -> Simulator | TeamGridWorld:
    """The team's world ``config.dynamics`` asks for: MuJoCo (physics or kinematic, a
    :class:`~mjexplore.sim.simulator.Simulator` of ``len(starts)`` robots) or the grid
    (:class:`TeamGridWorld`)."""
    config = config or SimConfig()
    if config.dynamics == "grid":
        return TeamGridWorld(scene, starts, config)
    return Simulator(scene, config, starts)


__all__ = ["TeamGridLidar", "TeamGridRobot", "TeamGridWorld", "TeammateBody", "make_team_world"]
