"""The motion model the kinematic and grid worlds share: command limits, the acceleration
limiter, closed-form unicycle moves, and the body's clearance from the ground-truth walls.

Poses are (x, y, yaw) of ``base_link`` in the ``map`` frame (metres, radians); twists are
(forward speed m/s, yaw rate rad/s). Everything here works on plain floats: it runs every
sample period.
"""

from __future__ import annotations

import math

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap
from mjexplore.robot import TURTLEBOT3_WAFFLE, MotionProfile, limit_wheel_speeds
from mjexplore.scenes.scene import clearance

# The base plate's bounding circle: centre behind base_link, radius the half-diagonal of the
# 0.281 x 0.266 m plate (the wheels lie within it), metres.
BODY_CENTRE_X = -0.064
BODY_RADIUS = 0.194


def limit_command(profile: MotionProfile, linear: float, angular: float,
                  ) -> tuple[float, float]:
    """A velocity target (m/s, rad/s) clipped to the profile's speed limits, then scaled
    down (both together) where a wheel would turn faster than its limit."""
    p = profile
    return limit_wheel_speeds(
        min(max(float(linear), -p.max_linear_speed), p.max_linear_speed),
        min(max(float(angular), -p.max_angular_speed), p.max_angular_speed),
        p.max_wheel_speed)


def ramp_command(current: tuple[float, float], target: tuple[float, float],
                 profile: MotionProfile, period: float) -> tuple[float, float]:
    """One step of the acceleration limiter: the set-point ``period`` seconds after
    ``current`` on the way to ``target`` (both within the limits of
    :func:`limit_command`)."""
    p = profile
    dv = p.max_linear_accel * period
    dw = p.max_angular_accel * period
    v0, w0 = current
    v = v0 + min(max(target[0] - v0, -dv), dv)
    w = w0 + min(max(target[1] - w0, -dw), dw)
    if limit_wheel_speeds(v, w, p.max_wheel_speed) != (v, w):
        # Off the straight line to the target, a wheel can be too fast: step along that
        # line instead (both ends are within the wheel limits, so all of it is).
        ev, ew = target[0] - v0, target[1] - w0
        f = min(1.0, dv / abs(ev) if ev else 1.0, dw / abs(ew) if ew else 1.0)
        v, w = v0 + f * ev, w0 + f * ew
    return v, w


def mean_ramp_twist(start: tuple[float, float], end: tuple[float, float], step0: int,
                    step1: int, period_steps: int) -> tuple[float, float]:
    """Mean twist over physics steps ``step0`` to ``step1`` while the set-point ramps
    linearly from ``start`` to ``end`` over each sample period of ``period_steps`` steps."""
    f0 = (step0 % period_steps) / period_steps
    a = f0 + 0.5 * (step1 - step0) / period_steps
    return start[0] + (end[0] - start[0]) * a, start[1] + (end[1] - start[1]) * a


def wall_clearance(ground_truth: GridMap | None) -> np.ndarray:
    """Distance (m) from each ground-truth cell centre to the nearest wall surface.

    Every cell that is not free blocks, unknown ones too: the MJCF makes them walls. A wall
    cell's surface lies half a cell nearer than its centre.

    Raises:
        UserInputError: the scene has no ground truth.
    """
    if ground_truth is None:
        raise UserInputError("the kinematic and grid worlds need the scene's ground-truth map "
                             "(map.yaml beside scene.xml): regenerate the scene.")
    return clearance(ground_truth.free, ground_truth.resolution)


def body_clearance(wall_clearance: np.ndarray, ground_truth: GridMap, x: float, y: float,
                   yaw: float) -> float:
    """Distance from the body's centre at pose (x, y, yaw) to the nearest wall surface, in
    metres (-inf off the map), given :func:`wall_clearance` of ``ground_truth``."""
    cx = x + BODY_CENTRE_X * math.cos(yaw)
    cy = y + BODY_CENTRE_X * math.sin(yaw)
    col = math.floor((cx - ground_truth.origin[0]) / ground_truth.resolution)
    row = math.floor((cy - ground_truth.origin[1]) / ground_truth.resolution)
    rows, cols = wall_clearance.shape
    if not (0 <= row < rows and 0 <= col < cols):
        return -math.inf
    return float(wall_clearance[row, col])


def body_blocked(wall_clearance: np.ndarray, ground_truth: GridMap, x: float, y: float,
                 yaw: float) -> bool:
    """Whether the body's bounding circle at pose (x, y, yaw) reaches into a wall (or off
    the map), given :func:`wall_clearance` of ``ground_truth``."""
    return body_clearance(wall_clearance, ground_truth, x, y, yaw) < BODY_RADIUS


def unicycle_move(x: float, y: float, yaw: float, v: float, w: float, duration: float,
                  ) -> tuple[float, float, float, float]:
    """Exact unicycle motion at the constant twist (v, w) for ``duration`` seconds.

    Returns:
        The end pose (x, y, yaw; yaw not wrapped) and the chord length travelled in metres
        (signed like ``v``).
    """
    half = 0.5 * w * duration
    # The chord of the arc points along the mean heading; it is sin(h)/h of the arc long.
    chord = v * duration * (math.sin(half) / half if abs(half) > 1e-9 else 1.0)
    mid = yaw + half
    return x + chord * math.cos(mid), y + chord * math.sin(mid), yaw + 2.0 * half, chord


def kinematic_step(wall_clearance: np.ndarray, ground_truth: GridMap,
                   pose: tuple[float, float, float], twist: tuple[float, float],
                   duration: float) -> tuple[tuple[float, float, float], tuple[float, float],
                                             tuple[float, float], bool]:
    """One move of the kinematic and grid worlds: the unicycle at ``twist`` for
    ``duration`` seconds from ``pose``, refused where the body would reach into a wall.

    Returns:
        The new pose (yaw not wrapped), the twist moved at ((0, 0) when refused), the
        (left, right) wheel angle increments in radians that wheel odometry reads as this
        move (so that it reads the truth), and whether the move was refused.
    """
    x, y, yaw, chord = unicycle_move(*pose, *twist, duration)
    after = body_clearance(wall_clearance, ground_truth, x, y, yaw)
    # A move that reaches into a wall is refused, unless it takes the body no nearer to
    # the walls than it is (on the clearance grid a body can sit where every small move
    # but one sideways, which a differential drive cannot make, reads nearer).
    if after < BODY_RADIUS and after < body_clearance(wall_clearance, ground_truth, *pose):
        return pose, (0.0, 0.0), (0.0, 0.0), True
    turn = (yaw - pose[2]) * TURTLEBOT3_WAFFLE.wheel_separation / 2
    r = TURTLEBOT3_WAFFLE.wheel_radius
    return (x, y, yaw), twist, ((chord - turn) / r, (chord + turn) / r), False
