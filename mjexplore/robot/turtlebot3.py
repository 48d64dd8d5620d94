"""Turtlebot3 Waffle dimensions and motion profiles (see assets/turtlebot3_waffle/README.md).

Frames follow REP-103/105: ``base_link`` at the middle of the wheel axle, x forward,
y left, z up; ``base_scan`` is the lidar frame.
"""

from __future__ import annotations

import dataclasses
import math
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
        wheel_width: Width of a drive wheel's tyre.
        length: Overall length of the collision footprint (x).
        width: Overall width of the collision footprint (y, over the wheels).
        footprint_radius: Radius of the circle about ``base_link`` that contains the body
            (the area swept when turning in place); used for clearance and inflation.
        scan_offset: (x, y, z) of ``base_scan`` in ``base_link``.
        imu_offset: (x, y, z) of ``imu_link`` in ``base_link``.
    """

    wheel_radius: float = 0.033
    wheel_separation: float = 0.287
    wheel_width: float = 0.019
    length: float = 0.281
    width: float = 0.306
    footprint_radius: float = 0.26
    scan_offset: tuple[float, float, float] = (-0.064, 0.0, 0.122)
    imu_offset: tuple[float, float, float] = (-0.032, 0.0, 0.068)


@dataclasses.dataclass(frozen=True, kw_only=True)
class WheelMotor:
    """A drive wheel's gearmotor (must agree with the actuators of ``robot.xml``).

    Attributes:
        name: Motor model.
        no_load_speed: Output speed without load in rad/s.
        stall_torque: Output torque at stall in N m (the actuators' force range).
        gear_ratio: Gearbox reduction.
    """

    name: str
    no_load_speed: float
    stall_torque: float
    gear_ratio: float


TURTLEBOT3_WAFFLE = RobotGeometry()
# The Waffle's Dynamixel XM430-W210-T at 12 V (ROBOTIS e-Manual): 77 rpm without load,
# 3.0 N m stall torque, 212.6:1. turtlebot3's firmware caps a wheel at 337 x 0.229 rpm.
XM430_W210 = WheelMotor(name="XM430-W210", no_load_speed=77 * 2 * math.pi / 60,
                        stall_torque=3.0, gear_ratio=212.6)


@dataclasses.dataclass(frozen=True, kw_only=True)
class MotionProfile:
    """Velocity and acceleration limits and the default lidar range of a setting.

    Attributes:
        name: Profile name.
        max_linear_speed: |v| limit in m/s.
        max_angular_speed: |omega| limit in rad/s.
        max_linear_accel: |dv/dt| limit in m/s^2.
        max_angular_accel: |domega/dt| limit in rad/s^2.
        max_wheel_speed: |wheel speed| limit in rad/s; a (v, omega) that needs more is
            scaled down, keeping its curvature (see :func:`limit_wheel_speeds`).
        lidar_range: Default lidar maximum range in metres.
    """

    name: str
    max_linear_speed: float
    max_angular_speed: float
    max_linear_accel: float = 2.5
    max_angular_accel: float = 3.2
    max_wheel_speed: float = XM430_W210.no_load_speed
    lidar_range: float = 6.0


MOTION_PROFILES = {
    # The paper's Gazebo setting: 0.5 m/s, 1.8 rad/s, 6 m lidar. Its 0.5 m/s needs a wheel
    # speed of 15.2 rad/s, twice the XM430's: the wheels are limited to that speed.
    "sim": MotionProfile(name="sim", max_linear_speed=0.5, max_angular_speed=1.8,
                         max_wheel_speed=0.5 / TURTLEBOT3_WAFFLE.wheel_radius),
    # The paper's real robot: 0.18 m/s, 1.8 rad/s, 5 m lidar; the XM430's wheel speed.
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


def limit_wheel_speeds(v: float, omega: float, max_wheel_speed: float,
                       geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> tuple[float, float]:
    """Scales (v, omega) down so that neither wheel turns faster than ``max_wheel_speed``.

    Both are scaled by the same factor, so the path's curvature is kept (turtlebot3's
    firmware clips each wheel on its own, which bends the path instead).

    Args:
        v: Forward speed of ``base_link`` in m/s.
        omega: Yaw rate in rad/s.
        max_wheel_speed: Wheel speed limit in rad/s.
        geometry: Robot dimensions.

    Returns:
        The limited (v, omega), plain floats.
    """
    fastest = (abs(v) + abs(omega) * geometry.wheel_separation / 2) / geometry.wheel_radius
    if fastest <= max_wheel_speed:
        return v, omega
    scale = max_wheel_speed / fastest
    return v * scale, omega * scale
