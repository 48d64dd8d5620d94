"""A velocity check against moving bodies: the command slowed or stopped before it touches.

The planner keeps its paths clear of the bodies it knows (:mod:`mjexplore.navigation.bodies`),
but a path is followed by pure pursuit from a pose that lags the plan, and people walk into
it between two plans. Like Nav2's collision monitor, :func:`safe_command` rolls the
commanded twist forward over a short horizon, with each tracked body moving on at its own
velocity, and keeps the command only if the robot's bounding circle stays ``margin`` metres
clear of every body; otherwise it tries the same turn at lower forward speeds, then turning
in place, then standing still. A command that opens a gap that is already small is kept
(the robot may always back off or turn away).
"""

from __future__ import annotations

import numpy as np

from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS

# The forward speeds tried, as shares of the commanded one, before turning in place.
SPEED_SHARES = (1.0, 0.5, 0.25, 0.0)


def _least_gap(pose: np.ndarray, v: float, w: float, bodies: np.ndarray,
               velocities: np.ndarray, radius: float, times: np.ndarray) -> np.ndarray:
    """Gap (metres) between the robot's bounding circle and the nearest body at each of
    ``times``, the robot driving (v, w) from ``pose`` and each body moving on straight."""
    x, y, yaw = pose
    heading = yaw + w * times
    if abs(w) > 1e-6:
        px = x + v / w * (np.sin(heading) - np.sin(yaw))
        py = y - v / w * (np.cos(heading) - np.cos(yaw))
    else:
        px, py = x + v * times * np.cos(yaw), y + v * times * np.sin(yaw)
    cx = px + BODY_CENTRE_X * np.cos(heading)
    cy = py + BODY_CENTRE_X * np.sin(heading)
    bx = bodies[:, :1] + velocities[:, :1] * times[None]
    by = bodies[:, 1:] + velocities[:, 1:] * times[None]
    return (np.hypot(bx - cx[None], by - cy[None]) - BODY_RADIUS - radius).min(axis=0)


def safe_command(pose: np.ndarray, v: float, w: float, bodies: np.ndarray,
                 velocities: np.ndarray, radius: float, horizon: float = 1.0,
                 margin: float = 0.1, dt: float = 0.1) -> tuple[float, float]:
    """The twist to drive instead of (v, w) so as not to come within ``margin`` metres of
    a moving body within ``horizon`` seconds.

    Args:
        pose: The robot's (x, y, yaw), ``map`` frame.
        v: Commanded forward speed, m/s.
        w: Commanded turn rate, rad/s.
        bodies: (k, 2) the bodies' centres, ``map`` frame.
        velocities: (k, 2) their velocities, m/s.
        radius: A body's radius, metres.
        horizon: How far ahead the motion is rolled out, seconds.
        margin: The least gap kept, metres.
        dt: Time step of the roll-out, seconds.

    Returns:
        (v, w) itself when it keeps the gap (or opens it), else the first of: the same turn
        at a lower forward speed (:data:`SPEED_SHARES`), turning in place, standing still.
    """
    bodies = np.asarray(bodies, float).reshape(-1, 2)
    if not len(bodies):
        return v, w
    velocities = np.asarray(velocities, float).reshape(-1, 2)
    pose = np.asarray(pose, float)
    times = np.arange(1, int(round(horizon / dt)) + 1) * dt
    now = _least_gap(pose, 0.0, 0.0, bodies, np.zeros_like(velocities), radius,
                     np.zeros(1))[0]

    def keeps(v_: float, w_: float) -> bool:
        gaps = _least_gap(pose, v_, w_, bodies, velocities, radius, times)
        return bool(gaps.min() >= min(margin, now) - 1e-9)

    for share in SPEED_SHARES:
        if keeps(v * share, w):
            return v * share, w
    return 0.0, 0.0


__all__ = ["SPEED_SHARES", "safe_command"]
