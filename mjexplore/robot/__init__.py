"""The Turtlebot3-Waffle-like robot: model file, dimensions and motion profiles."""

from mjexplore.robot.turtlebot3 import (
    MOTION_PROFILES,
    ROBOT_XML,
    TURTLEBOT3_WAFFLE,
    MotionProfile,
    RobotGeometry,
    motion_profile,
)

__all__ = [
    "MOTION_PROFILES",
    "ROBOT_XML",
    "TURTLEBOT3_WAFFLE",
    "MotionProfile",
    "RobotGeometry",
    "motion_profile",
]
