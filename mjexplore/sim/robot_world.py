"""What every world a robot runs in shares: commands, and the state read back the same way.

:class:`~mjexplore.sim.simulator.Simulator` (MuJoCo) and
:class:`~mjexplore.sim.grid_world.GridWorld` subclass :class:`RobotWorld`; both carry people
(:mod:`mjexplore.sim.people`) with the functions below: checked before a world is built
(:func:`people_to_walk`), drawn at a reset (:func:`new_crowd`), walked every sample period
(:func:`walk_crowd`) and touched (:func:`people_contacts`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap
from mjexplore.robot import MotionProfile
from mjexplore.sim.kinematics import KinematicsLog, KinematicsRecorder
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS, limit_command
from mjexplore.sim.odometry import WheelOdometry
from mjexplore.sim.people import Crowd, PeopleConfig, check_capacity, for_scene
from mjexplore.sim.people import capacity as people_capacity

# Contacts closer in time than this belong to one collision (a robot pushing against a wall
# or a person bounces on and off it).
COLLISION_GAP_S = 0.5
PEOPLE_STREAM = 51  # The people's generator: [seed, PEOPLE_STREAM].


def people_to_walk(people: PeopleConfig | None, ground_truth: GridMap | None,
                   ) -> PeopleConfig | None:
    """The people a world carries (None: nobody), their count fixed for this building (a
    density's share of its floor: :func:`~mjexplore.sim.people.for_scene`) and checked
    before anything is built: they walk on the ground truth, and the free space must hold
    them.

    Raises:
        UserInputError: no ground truth, or more people than its free space holds.
    """
    if people is None or (people.count <= 0 and people.density <= 0):
        return None
    if ground_truth is None:
        raise UserInputError("people walk on the scene's ground-truth map, and this scene "
                             "has none.")
    people = for_scene(people, ground_truth)
    if people.count <= 0:
        return None
    check_capacity(people.count, people_capacity(people, ground_truth))
    return people


def new_crowd(people: PeopleConfig, ground_truth: GridMap, seed: int, poses: list,
              ) -> Crowd:
    """A world's crowd at a reset: drawn from the seed's own stream (a run without people
    draws nothing of it), starting clear of the robots' ``poses`` ((x, y, ...) each)."""
    return Crowd(people, ground_truth, np.random.default_rng([seed, PEOPLE_STREAM]),
                 keep_clear=np.array([q[:2] for q in poses]))


def walk_crowd(crowd: Crowd, duration: float, robots: Sequence[RobotWorld]) -> None:
    """Advances the crowd by ``duration`` seconds with the robots' bodies where they are."""
    crowd.step(duration, np.array([r.body_centre for r in robots]), BODY_RADIUS)


def people_contacts(crowd: Crowd, robots: Sequence[RobotWorld],
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per robot, whether it touches a person now (bodies within 1 cm, or a kinematic move
    refused) and the gap (metres) between its body's bounding circle and the nearest
    person."""
    n = len(robots)
    if not len(crowd):
        return np.zeros(n, bool), np.full(n, math.inf)
    gap = crowd.distances_to(np.array([r.body_centre for r in robots])) - BODY_RADIUS
    return (gap < 0.01) | np.array([r._kinematic_person for r in robots]), gap


class RobotWorld:
    """The command and state accessors of a world; subclasses step it.

    Subclasses set ``profile``, ``odometry``, ``_kinematics`` (a
    :class:`KinematicsRecorder`), ``_start`` (the pose at reset), and keep
    ``_steps`` (physics steps since reset), ``_sample_every`` (physics steps per sample),
    ``_target`` (the limited velocity target), ``_cmd`` (the set-point), ``_scan`` (the
    latest scan) and ``_in_contact``; they define ``_ramp`` (the acceleration limiter's
    step from ``_cmd_base`` to ``_target``).
    """

    profile: MotionProfile
    _kinematics: KinematicsRecorder
    _steps: int
    _sample_every: int
    _target: tuple[float, float]
    _cmd: tuple[float, float]
    _scan: LaserScan
    _in_contact: bool
    _start: np.ndarray
    odometry: WheelOdometry
    # A team's robots (this one among them; a robot alone's is itself), the contacts with
    # them, and the moves they refused.
    robots: list
    robot_contacts: int
    _teammate_contact: bool
    _last_teammate: float
    _kinematic_person: bool
    # Among people: the contacts with them, the least gap to one, and when one was touched.
    people_collisions: int
    people_min_distance: float
    _last_person: float

    @property
    def odom_pose(self) -> np.ndarray:
        """Wheel-odometry (x, y, yaw) of ``base_link`` in the ``odom`` frame.

        The ``odom`` frame coincides with the start pose at reset (``map -> odom`` is the
        start pose); it drifts from the truth with wheel slip and the odometry's errors.
        """
        return self.odometry.pose.copy()

    @property
    def odom_origin(self) -> np.ndarray:
        """Pose of the ``odom`` frame in the ``map`` frame (the pose at reset)."""
        return self._start.copy()

    @property
    def latest_scan(self) -> LaserScan:
        return self._scan

    def scan_now(self) -> LaserScan | None:
        """A scan at the current pose and time that the world's scan schedule skipped, or
        None when every scan instant has had its scan (worlds scanning at the lidar's
        rate; the grid world scanning by travel overrides this)."""
        return None

    @property
    def pose(self) -> np.ndarray:
        """Ground-truth (x, y, yaw) of ``base_link`` in the ``map`` frame."""
        raise NotImplementedError

    @property
    def time(self) -> float:
        """Simulated time since reset in seconds."""
        raise NotImplementedError

    @property
    def in_collision(self) -> bool:
        """Touching a wall, a teammate or a person."""
        return self._in_contact or self._teammate_contact

    @property
    def body_centre(self) -> tuple[float, float]:
        """Centre of the body's bounding circle (radius ``BODY_RADIUS``), ``map`` frame."""
        x, y, yaw = self.pose
        return x + BODY_CENTRE_X * math.cos(yaw), y + BODY_CENTRE_X * math.sin(yaw)

    def _people(self) -> Any:
        """The world's crowd (:class:`~mjexplore.sim.people.Crowd`), or None."""
        return None

    def _moved_into_teammate(self, centre_before: tuple[float, float]) -> bool:
        """Whether the move just made, from a body centre at ``centre_before``, brought the
        body into a person's or a teammate's (discs overlapping, and nearer than before);
        ``_kinematic_person`` says which."""
        after = self.body_centre
        crowd = self._people()
        self._kinematic_person = False
        if crowd is not None and len(crowd):
            reach = BODY_RADIUS + crowd.config.radius
            d_after = np.hypot(*(crowd.positions - after).T)
            d_before = np.hypot(*(crowd.positions - centre_before).T)
            if ((d_after < reach) & (d_after < d_before)).any():
                self._kinematic_person = True
                return True
        for other in self.robots:
            if other is self:
                continue
            ox, oy = other.body_centre
            d = math.hypot(after[0] - ox, after[1] - oy)
            if d < 2 * BODY_RADIUS and d < math.hypot(centre_before[0] - ox,
                                                      centre_before[1] - oy):
                return True
        return False

    def _note_teammate(self, touching: bool) -> None:
        """Counts a contact with a teammate (those less than ``COLLISION_GAP_S`` apart as
        one)."""
        t = self.time
        if touching:
            if t - self._last_teammate > COLLISION_GAP_S:
                self.robot_contacts += 1
            self._last_teammate = t
        self._teammate_contact = touching

    def _reset_people(self) -> None:
        """No contact with a person yet, and no gap measured."""
        self._kinematic_person = False
        self.people_collisions = 0
        self.people_min_distance = math.inf
        self._last_person = -math.inf

    def _note_people(self, touching: bool, gap: float) -> None:
        """Counts a contact with a person (those less than ``COLLISION_GAP_S`` apart as
        one) and keeps the least ``gap`` (metres) between the body's bounding circle and a
        person."""
        t = self.time
        if touching:
            if t - self._last_person > COLLISION_GAP_S:
                self.people_collisions += 1
            self._last_person = t
        self._teammate_contact = self._teammate_contact or touching
        self.people_min_distance = min(self.people_min_distance, gap)

    @property
    def command_applied(self) -> np.ndarray:
        """(v, omega) set-point, after the acceleration limiter, reached at the end of the
        current sample period."""
        return np.array(self._cmd)

    def kinematics(self) -> KinematicsLog:
        """Velocity and acceleration samples since reset."""
        return self._kinematics.log()

    @property
    def kinematics_rows(self) -> np.ndarray:
        """The raw kinematics samples so far (a view, no copy): columns t, v, omega, ..."""
        return self._kinematics.rows

    def command(self, linear: float, angular: float) -> None:
        """Sets the velocity target (m/s, rad/s), clipped to the profile's limits.

        Speed and yaw rate are clipped to their limits, then both are scaled down together
        where a wheel would turn faster than the profile's wheel speed limit. The applied
        command approaches the target no faster than the profile's acceleration limits,
        updated every sample period.
        """
        self._target = limit_command(self.profile, linear, angular)
        if self._steps % self._sample_every == 0:
            self._ramp()

    def _ramp(self) -> None:
        raise NotImplementedError
