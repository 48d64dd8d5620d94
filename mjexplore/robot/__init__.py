"""The Turtlebot3-Waffle-like robot: model file, dimensions, motors and motion profiles."""

from mjexplore.robot.turtlebot3 import (
    MOTION_PROFILES,
    ROBOT_XML,
    TURTLEBOT3_WAFFLE,
    XM430_W210,
    MotionProfile,
    RobotGeometry,
    WheelMotor,
    limit_wheel_speeds,
    motion_profile,
)

__all__ = [
    "MOTION_PROFILES",
    "ROBOT_XML",
    "TURTLEBOT3_WAFFLE",
    "XM430_W210",
    "MotionProfile",
    "RobotGeometry",
    "WheelMotor",
    "limit_wheel_speeds",
    "motion_profile",
]
