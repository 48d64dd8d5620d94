"""Turtlebot3 Waffle dimensions and motion profiles (see assets/turtlebot3_waffle/README.md).

Frames follow REP-103/105: ``base_link`` at the middle of the wheel axle, x forward,
y left, z up; ``base_scan`` is the lidar frame.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from mjexplore.errors import UserInputError

ROBOT_XML = Path(__file__).resolve().parents[2] / "assets" / "turtlebot3_waffle" / "robot.xml"


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotGeometry:
    """Dimensions the software needs, in metres (must agree with ``robot.xml``).

    Attributes:
        wheel_radius: Drive wheel radius.
        wheel_separation: Distance between the drive wheels' contact points.
        footprint_radius: Radius of the circle about ``base_link`` that contains the body
            (the area swept when turning in place); used for clearance and inflation.
        scan_offset: (x, y, z) of ``base_scan`` in ``base_link``.
    """

    wheel_radius: float = 0.033
    wheel_separation: float = 0.287
    footprint_radius: float = 0.26
    scan_offset: tuple[float, float, float] = (-0.064, 0.0, 0.122)


TURTLEBOT3_WAFFLE = RobotGeometry()


@dataclasses.dataclass(frozen=True, kw_only=True)
class MotionProfile:
    """Velocity and acceleration limits and the default lidar range of a setting.

    Attributes:
        name: Profile name.
        max_linear_speed: |v| limit in m/s.
        max_angular_speed: |omega| limit in rad/s.
        max_linear_accel: |dv/dt| limit in m/s^2.
        max_angular_accel: |domega/dt| limit in rad/s^2.
        lidar_range: Default lidar maximum range in metres.
    """

    name: str
    max_linear_speed: float
    max_angular_speed: float
    max_linear_accel: float = 2.5
    max_angular_accel: float = 3.2
    lidar_range: float = 6.0


MOTION_PROFILES = {
    # The paper's Gazebo setting: 0.5 m/s, 1.8 rad/s, 6 m lidar.
    "sim": MotionProfile(name="sim", max_linear_speed=0.5, max_angular_speed=1.8),
    # The paper's real robot: 0.18 m/s, 1.8 rad/s, 5 m lidar.
    "real": MotionProfile(name="real", max_linear_speed=0.18, max_angular_speed=1.8,
                          lidar_range=5.0),
}


def motion_profile(name: str) -> MotionProfile:
    """Looks up a motion profile by name.

    Raises:
        UserInputError: unknown profile name.
    """
    try:
        return MOTION_PROFILES[name]
    except KeyError:
        raise UserInputError(f"unknown motion profile {name!r}: use one of "
                             f"{', '.join(MOTION_PROFILES)}.") from None


def wheel_speeds(v: float, omega: float, geometry: RobotGeometry = TURTLEBOT3_WAFFLE,
                 ) -> np.ndarray:
    """Differential-drive inverse kinematics.

    Args:
        v: Forward speed of ``base_link`` in m/s.
        omega: Yaw rate in rad/s (counter-clockwise positive).
        geometry: Robot dimensions.

    Returns:
        [left, right] wheel angular velocities in rad/s.
    """
    half = geometry.wheel_separation / 2
    return np.array([v - omega * half, v + omega * half]) / geometry.wheel_radius
