"""Wheel odometry integrated from the wheel joints, as a robot's encoders would give it.

The pose is dead-reckoned from the change of each wheel's angle between samples (the
integral of the joint velocity), so wheel slip and integration error make it drift from
the ground truth the way a real robot's odometry does.
"""

from __future__ import annotations

import math

import numpy as np

from mjexplore.robot import TURTLEBOT3_WAFFLE, RobotGeometry


class WheelOdometry:
    """Differential-drive dead reckoning in the ``odom`` frame.

    Args:
        geometry: Wheel radius and separation used by the odometry (the robot's nominal
            dimensions).
    """

    def __init__(self, geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> None:
        self.geometry = geometry
        self._pose = (0.0, 0.0, 0.0)
        self._twist = (0.0, 0.0)
        self._last_angles: tuple[float, float] | None = None
        self._last_time = 0.0

    @property
    def pose(self) -> np.ndarray:
        """(x, y, yaw) of ``base_link`` in the ``odom`` frame, metres and radians."""
        return np.array(self._pose)

    @property
    def pose_tuple(self) -> tuple[float, float, float]:
        return self._pose

    @property
    def twist(self) -> np.ndarray:
        """(forward speed m/s, yaw rate rad/s) over the last update."""
        return np.array(self._twist)

    def reset(self, wheel_angles: np.ndarray, stamp: float,
              pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Starts integrating from ``pose`` with the current wheel angles (radians)."""
        self._pose = tuple(float(v) for v in pose)
        self._twist = (0.0, 0.0)
        self._last_angles = (float(wheel_angles[0]), float(wheel_angles[1]))
        self._last_time = stamp

    def update(self, wheel_angles: np.ndarray, stamp: float) -> None:
        """Integrates the motion since the last update (exact for constant curvature)."""
        assert self._last_angles is not None, "call reset() first"
        left, right = float(wheel_angles[0]), float(wheel_angles[1])
        r = self.geometry.wheel_radius
        d_left = (left - self._last_angles[0]) * r
        d_right = (right - self._last_angles[1]) * r
        self._last_angles = (left, right)
        ds = 0.5 * (d_left + d_right)
        dtheta = (d_right - d_left) / self.geometry.wheel_separation
        x, y, yaw = self._pose
        heading = yaw + 0.5 * dtheta
        yaw = (yaw + dtheta + math.pi) % (2 * math.pi) - math.pi
        self._pose = (x + ds * math.cos(heading), y + ds * math.sin(heading), yaw)
        dt = stamp - self._last_time
        if dt > 0:
            self._twist = (ds / dt, dtheta / dt)
        self._last_time = stamp


def odom_in_map(origin: np.ndarray, odom: np.ndarray) -> np.ndarray:
    """Composes ``map -> odom`` (x, y, yaw) with poses (n, 3) in ``odom``: poses in ``map``."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    x = origin[0] + c * odom[:, 0] - s * odom[:, 1]
    y = origin[1] + s * odom[:, 0] + c * odom[:, 1]
    yaw = (odom[:, 2] + origin[2] + math.pi) % (2 * math.pi) - math.pi
    return np.column_stack([x, y, yaw])
