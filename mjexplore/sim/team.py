"""A team of robots in one MuJoCo world: N Turtlebots in one model, stepped together.

:class:`TeamSimulator` compiles the scene's MJCF with its robot replaced by N copies
(:func:`mjexplore.scenes.team.team_spec`) and steps them on one clock: physics (or the
kinematic motion) for all, then, on the same grids of physics steps as
:class:`~mjexplore.sim.simulator.Simulator`, every robot's odometry, kinematics and
collision sample, acceleration limiter and lidar scan. Each robot is a
:class:`TeamRobot`: the single robot's interface (``pose``, ``odom_pose``, ``command``,
``latest_scan``, ``kinematics()``, ``collisions``, ...), so that everything above the world
treats it as the one robot of an episode, except that only the team steps.

The robots see each other: each lidar casts against the walls (as a single robot's) and
against the teammates' silhouettes, and keeps the nearer return. They collide: in physics
through MuJoCo's contacts, in the kinematic mode by refusing a move that brings two bodies'
bounding circles into each other. ``collisions`` counts a robot's wall collisions as the
single robot's does; robot-robot contacts are counted apart (``robot_contacts`` per robot,
:attr:`TeamSimulator.robot_collisions` per pair), contacts less than ``COLLISION_GAP_S``
apart counting as one. A robot touching a teammate reads ``in_collision`` as when it
touches a wall.

Robot 0 draws its sensor noise and odometry errors from the config's seed, as a single
robot does; robot ``i > 0`` from a seed derived from it and ``i``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from typing import Protocol

import mujoco
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.robot import motion_profile
from mjexplore.scenes.scene import SceneFiles, load_scene_files
from mjexplore.scenes.team import SILHOUETTE, Pose, robot_prefix, team_spec
from mjexplore.sim.kinematics import KinematicsRecorder
from mjexplore.sim.lidar import LaserScan, Lidar, LidarConfig
from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS, wall_clearance
from mjexplore.sim.simulator import (
    BASE_BODY,
    COLLISION_GAP_S,
    SCAN_SITE,
    SimConfig,
    Simulator,
    _steps_per,
)


def float_pose(values) -> Pose:
    """A start pose (x, y, yaw) given as any three numbers, as floats."""
    x, y, yaw = (float(v) for v in values)
    return x, y, yaw


def robot_seed(seed: int, i: int) -> int:
    """The seed of robot ``i``'s noise and errors: ``seed`` itself for robot 0."""
    if i == 0:
        return seed
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def ray_boxes(origin: np.ndarray, vec: np.ndarray, centres: np.ndarray, rot: np.ndarray,
              half: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays against boxes whose axes include the vertical (upright bodies): the slab
    method in each box's horizontal frame, with the hit's height checked.

    Args:
        origin: (3,) the rays' origin, metres.
        vec: (n, 3) unit ray directions.
        centres: (k, 3) box centres.
        rot: (k, 3, 3) box orientations (columns: the box axes in the world).
        half: (3,) half sizes.

    Returns:
        (n,) distance to the nearest box hit (-1 for none), (n,) the box hit (-1), and
        (n, 3) the unit normal of the face hit.
    """
    n = len(vec)
    best = np.full(n, -1.0)
    which = np.full(n, -1, np.int64)
    normal = np.zeros((n, 3))
    for b in range(len(centres)):
        axes = rot[b][:, :2]  # The box's horizontal axes in the world.
        o = (origin - centres[b]) @ axes
        d = vec @ axes
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
            t1 = (-half[:2] - o) * inv
            t2 = (half[:2] - o) * inv
        tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
        near = tmin.max(axis=1)
        far = tmax.min(axis=1)
        z = origin[2] + near * vec[:, 2] - centres[b][2]
        hit = (near <= far) & (near > 0) & (np.abs(z) <= half[2])
        hit &= (best < 0) | (near < best)
        if not hit.any():
            continue
        best[hit] = near[hit]
        which[hit] = b
        face = np.argmax(tmin[hit], axis=1)
        sign = -np.sign(d[hit, face])
        normal[hit] = sign[:, None] * axes.T[face]
    return best, which, normal


class TeamLidar(Lidar):
    """A lidar that also sees the teammates' silhouettes (not its own robot's).

    The walls are cast as a single robot's lidar casts them; the silhouettes, upright
    boxes, by :func:`ray_boxes` (the same geometry MuJoCo's rays would meet, at a fraction
    of a full-model ``mj_multiRay``); the nearer return wins.

    Args:
        model: The team's compiled model.
        site: The lidar frame site's full name (``robot_{i}/base_scan``).
        config: Lidar settings.
        rng: Generator for noise and dropouts.
        silhouettes: Geom ids of the teammates' silhouettes (boxes).
    """

    def __init__(self, model: mujoco.MjModel, site: str, config: LidarConfig,
                 rng: np.random.Generator, silhouettes: list[int]) -> None:
        super().__init__(model, site, config, rng)
        self._silhouettes = np.asarray(silhouettes, np.int64)
        self._half = model.geom_size[self._silhouettes[0]].copy() if len(silhouettes) else None

    def _multi_ray(self, origin: np.ndarray, data: mujoco.MjData, i0: int, i1: int) -> None:
        super()._multi_ray(origin, data, i0, i1)
        ids = self._silhouettes
        if len(ids) == 0:
            return
        assert self._half is not None  # Set whenever there are silhouettes.
        centres = data.geom_xpos[ids]
        reach = self.config.range_max + 0.3
        near = np.hypot(centres[:, 0] - origin[0], centres[:, 1] - origin[1]) <= reach
        if not near.any():
            return
        dist, which, normal = ray_boxes(np.asarray(origin, float), self._vec[i0:i1],
                                        centres[near],
                                        data.geom_xmat[ids[near]].reshape(-1, 3, 3), self._half)
        walls = self._dist[i0:i1]
        nearer = (dist >= 0) & ((walls < 0) | (dist < walls))
        if nearer.any():
            walls[nearer] = dist[nearer]
            self._geomid[i0:i1][nearer] = ids[near][which[nearer]]
            if self._normal is not None:
                self._normal[i0:i1][nearer] = normal[nearer]


class _Team(Protocol):
    """What a robot of a team sees of its team (:class:`TeamSimulator`, the grid's team)."""

    @property
    def robots(self) -> Sequence[TeammateBody]: ...


class TeammateBody:
    """What a robot of a team adds to its world: contacts with teammates count as
    collisions, and its body's bounding circle for the teammates' costmaps and lidars."""

    _in_contact: bool
    _teammate_contact: bool
    _team: _Team
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


class TeamRobot(TeammateBody, Simulator):
    """One robot of a :class:`TeamSimulator`: the single robot's interface; the team steps.

    Attributes:
        index: The robot's number in the team.
        name: Its namespace, ``robot_{index}``.
        collisions: Wall collisions since reset (as :attr:`Simulator.collisions`).
        robot_contacts: Contacts with teammates since reset, those less than
            ``COLLISION_GAP_S`` apart counting as one.
    """

    _team: TeamSimulator

    def __init__(self, team: TeamSimulator, index: int) -> None:  # noqa: D107
        # Not Simulator.__init__: the team owns the model, the data and the clock.
        self._team = team
        self.index = index
        self.name = robot_prefix(index).rstrip("/")
        self.config = dataclasses.replace(team.config, seed=robot_seed(team.config.seed, index))
        self.scene = team.scene
        self.model, self.data = team.model, team.data
        self.profile = team.profile
        self._bind_robot(robot_prefix(index))
        self._is_wall_geom = team._is_wall_geom
        self._own_geoms = team.geom_robot == index
        self._sample_every = team._sample_every
        self._scan_every = team._scan_every
        self._rng = np.random.default_rng(self.config.seed)
        lidar_cfg = self.config.resolved_lidar()
        self.lidar = TeamLidar(self.model, robot_prefix(index) + SCAN_SITE, lidar_cfg,
                               self._rng, [g for j, g in enumerate(team._silhouettes)
                                           if j != index])
        self._skew = lidar_cfg.motion_skew
        self.odometry = self.config.make_odometry()
        self._kinematics = KinematicsRecorder()
        self._clearance = team._clearance
        self._start = np.zeros(3)

    @property
    # The team's clock, read-only here: the robot never steps alone.
    def _steps(self) -> int:  # type: ignore[override]
        return self._team._steps

    def reset(self, pose=None) -> LaserScan:
        raise TypeError("a team's robots are reset together: call TeamSimulator.reset")

    def step(self, duration: float) -> list[LaserScan]:
        raise TypeError("a team's robots step together: call TeamSimulator.step")

    def _place(self, pose: tuple[float, float, float]) -> None:
        x, y, yaw = pose
        self.data.qpos[self._qpos0:self._qpos0 + 7] = [x, y, self._z0, math.cos(yaw / 2), 0, 0,
                                                       math.sin(yaw / 2)]
        self._start = np.array([x, y, yaw], dtype=float)

    def _reset_state(self) -> None:
        """The single robot's reset, after the team has placed every robot."""
        self._target = (0.0, 0.0)
        self._cmd_base = (0.0, 0.0)
        self._cmd = (0.0, 0.0)
        self._apply_cmd()
        self.collisions = 0
        self.robot_contacts = 0
        self._in_contact = False
        self._teammate_contact = False
        self._last_contact = -math.inf
        self._last_teammate = -math.inf
        self._kinematic_contact = False
        self._kinematic_teammate = False
        self.odometry.reset(self.data.qpos[self._wheel_qpos], 0.0, true_yaw=self._start[2])
        self._kinematics.clear()
        self.lidar.clear_history()

    def _touching(self) -> bool:
        """Whether this robot touches a wall now (teammates are counted apart)."""
        if self._clearance is not None:
            return self._kinematic_contact
        return self._team._wall_touch[self.index]

    def _note_teammate(self, touching: bool) -> None:
        t = self.time
        if touching:
            if t - self._last_teammate > COLLISION_GAP_S:
                self.robot_contacts += 1
            self._last_teammate = t
        self._teammate_contact = touching

    def _move_kinematic(self, stop: int) -> None:
        """The single robot's kinematic move, refused as well where the body would come
        into a teammate's (bounding circles, and only a move that brings them nearer)."""
        i = self._qpos0
        q = self.data.qpos
        before = q[i:i + 7].copy(), q[self._wheel_qpos].copy()
        centre = self.body_centre
        super()._move_kinematic(stop)
        self._kinematic_teammate = self._moved_into_teammate(centre)
        if self._kinematic_teammate:
            q[i:i + 7], q[self._wheel_qpos] = before
            self.data.qvel[self._qvel0:self._qvel0 + 6] = 0.0


class TeamSimulator:
    """N robots in a scene's MuJoCo world, stepped together.

    Args:
        scene: A scene folder, its ``scene.xml`` or :class:`SceneFiles` (with its robot).
        starts: One start pose (x, y, yaw) per robot, ``map`` frame.
        config: Simulator settings, shared by the robots (``seed`` as the module says);
            ``dynamics`` 'physics' or 'kinematic'.

    Attributes:
        robots: The robots, in order.
        model: The team's compiled ``MjModel``.
        data: Its ``MjData``.
        geom_robot: (ngeom,) the robot each geom belongs to, -1 for the scene's.
        robot_collisions: Robot-robot collisions since reset: contacts between one pair
            less than ``COLLISION_GAP_S`` apart count as one.
    """

    def __init__(self, scene: str | os.PathLike | SceneFiles, starts: list,
                 config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        if self.config.dynamics not in ("physics", "kinematic"):
            raise UserInputError(f"a team runs in the physics or kinematic world, not "
                                 f"{self.config.dynamics!r}: use dynamics physics or "
                                 "kinematic.")
        self.scene = scene if isinstance(scene, SceneFiles) else load_scene_files(scene)
        self.starts = [float_pose(p) for p in starts]
        spec = team_spec(self.scene.xml, self.starts)
        try:
            self.model = spec.compile()
        except ValueError as exc:
            raise UserInputError(f"the team's MJCF from {str(self.scene.xml)!r} failed to "
                                 f"compile: {exc}. Regenerate the scene with "
                                 "'mjexplore scene-gen'.") from None
        self.data = mujoco.MjData(self.model)
        self.profile = motion_profile(self.config.profile)
        m = self.model
        self._is_wall_geom = (m.geom_bodyid == 0) & (m.geom_group == 0) & (
            m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE)
        body_robot = np.full(m.nbody, -1)
        for i in range(len(self.starts)):
            root = m.body(robot_prefix(i) + BASE_BODY).id
            body_robot[m.body_rootid == root] = i
        self.geom_robot = body_robot[m.geom_bodyid]
        dt = m.opt.timestep
        self._sample_every = _steps_per(1.0 / self.config.sample_rate_hz, dt, "sample")
        self._scan_every = _steps_per(1.0 / self.config.resolved_lidar().rate_hz, dt,
                                      "lidar scan")
        self._clearance = None
        if self.config.dynamics == "kinematic":
            if self.scene.ground_truth is None:
                raise UserInputError("the kinematic world needs the scene's ground-truth map.")
            self._clearance = wall_clearance(self.scene.ground_truth)
        self._steps = 0
        self._wall_touch = np.zeros(len(self.starts), bool)
        self._silhouettes = [m.geom(robot_prefix(i) + SILHOUETTE).id
                             for i in range(len(self.starts))]
        self.robots = [TeamRobot(self, i) for i in range(len(self.starts))]
        for r in self.robots[1:]:  # One tile cache of the walls for all lidars.
            r.lidar.static_scene = self.robots[0].lidar.static_scene
        self.reset()

    def __len__(self) -> int:
        return len(self.robots)

    @property
    def time(self) -> float:
        """Simulated time since reset in seconds."""
        return self._steps * self.model.opt.timestep

    @property
    def physics_fault(self) -> bool:
        return self.robots[0].physics_fault

    def warnings(self) -> dict[str, int]:
        return self.robots[0].warnings()

    def poses(self) -> np.ndarray:
        """(n, 3) ground-truth (x, y, yaw) of every robot's ``base_link``."""
        return np.array([r.pose for r in self.robots])

    def reset(self, poses: list | None = None) -> list[LaserScan]:
        """Puts every robot at rest at ``poses`` (default: the starts) at time 0.

        Returns:
            Each robot's first scan, taken at time 0.
        """
        m, d = self.model, self.data
        poses = self.starts if poses is None else [float_pose(p) for p in poses]
        if len(poses) != len(self.robots):
            raise ValueError(f"{len(poses)} poses for {len(self.robots)} robots")
        mujoco.mj_resetData(m, d)
        self._steps = 0
        for r, pose in zip(self.robots, poses):
            r._place(pose)
        mujoco.mj_forward(m, d)
        self.robot_collisions = 0
        self._pair_last: dict[tuple[int, int], float] = {}
        self._wall_touch[:] = False
        for r in self.robots:
            r._reset_state()
        self._sample()
        for r in self.robots:
            r._scan = r.lidar.scan(d, 0.0)
        return [r._scan for r in self.robots]

    def step(self, duration: float) -> list[list[LaserScan]]:
        """Advances simulated time by ``duration`` seconds (rounded to physics steps).

        Returns:
            Each robot's scans taken during the step, oldest first.
        """
        m, d = self.model, self.data
        target = self._steps + max(0, round(duration / m.opt.timestep))
        scans: list[list[LaserScan]] = [[] for _ in self.robots]
        while self._steps < target:
            next_sample = (self._steps // self._sample_every + 1) * self._sample_every
            next_scan = (self._steps // self._scan_every + 1) * self._scan_every
            stop = min(next_sample, next_scan, target)
            if self._clearance is None:
                mujoco.mj_step(m, d, nstep=stop - self._steps)
            else:
                for r in self.robots:
                    r._move_kinematic(stop)
            self._steps = stop
            if stop % self._sample_every == 0:
                self._sample()
                for r in self.robots:
                    r._cmd_base = r._cmd
                    r._ramp()
            if stop % self._scan_every == 0:
                mujoco.mj_kinematics(m, d)
                t = self.time
                for r, out in zip(self.robots, scans):
                    r._scan = r.lidar.scan(d, t)
                    out.append(r._scan)
        return scans

    def _sample(self) -> None:
        """Contacts, then every robot's sample (odometry, kinematics, collisions)."""
        touching = self._contacts()
        for r in self.robots:
            r._note_teammate(bool(touching[r.index]))
            r._sample()

    def _contacts(self) -> np.ndarray:
        """Which robots touch a teammate now; sets which touch a wall, and counts the
        pairs' collisions."""
        n = len(self.robots)
        teammate = np.zeros(n, bool)
        self._wall_touch[:] = False
        pairs: set[tuple[int, int]] = set()
        if self._clearance is not None:
            for r in self.robots:
                if r._kinematic_teammate:
                    teammate[r.index] = True
                    cx, cy = r.body_centre
                    for o in self.robots:
                        ox, oy = o.body_centre
                        if o is not r and math.hypot(cx - ox, cy - oy) < 2 * BODY_RADIUS + 0.01:
                            teammate[o.index] = True
                            pairs.add((min(r.index, o.index), max(r.index, o.index)))
        else:
            d = self.data
            if d.ncon:
                g = d.contact.geom[:d.ncon]
                owner = self.geom_robot[g]
                wall = self._is_wall_geom[g]
                self._wall_touch[owner[:, 0][wall[:, 1] & (owner[:, 0] >= 0)]] = True
                self._wall_touch[owner[:, 1][wall[:, 0] & (owner[:, 1] >= 0)]] = True
                both = (owner >= 0).all(axis=1) & (owner[:, 0] != owner[:, 1])
                for a, b in owner[both]:
                    teammate[[a, b]] = True
                    pairs.add((int(min(a, b)), int(max(a, b))))
        t = self.time
        for pair in pairs:
            if t - self._pair_last.get(pair, -math.inf) > COLLISION_GAP_S:
                self.robot_collisions += 1
            self._pair_last[pair] = t
        return teammate


__all__ = ["TeamLidar", "TeamRobot", "TeamSimulator", "ray_boxes", "robot_seed"]
