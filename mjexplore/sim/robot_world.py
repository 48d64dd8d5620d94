"""What every world a robot runs in shares: commands, and the state read back the same way.

:class:`~mjexplore.sim.simulator.Simulator` (MuJoCo) and
:class:`~mjexplore.sim.grid_world.GridWorld` subclass :class:`RobotWorld`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mjexplore.robot import MotionProfile
from mjexplore.sim.kinematics import KinematicsLog, KinematicsRecorder
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS, limit_command
from mjexplore.sim.odometry import WheelOdometry

# Contacts closer in time than this belong to one collision (a robot pushing against a wall
# or a person bounces on and off it).
COLLISION_GAP_S = 0.5


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
