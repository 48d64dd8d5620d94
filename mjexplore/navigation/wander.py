"""A reactive wandering controller: drive toward open space, turn away from walls.

It needs no map, only the latest scan; the demo and the simulator benchmark use it to
drive the robot through a scene in closed loop.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mjexplore.sim.lidar import LaserScan


@dataclasses.dataclass(frozen=True, kw_only=True)
class WanderConfig:
    """Wandering behaviour.

    Attributes:
        cruise_speed: Forward speed in open space, m/s.
        max_turn_rate: Largest yaw rate commanded, rad/s.
        stop_distance: Clearance ahead (m) below which the robot turns in place.
        slow_distance: Clearance ahead (m) below which it slows down.
        front_half_angle: Half-width of the sector counted as "ahead", radians.
        heading_gain: Yaw rate per radian of heading error toward the chosen gap, 1/s.
        commit_time: Seconds a chosen direction is kept before choosing again.
    """

    cruise_speed: float = 0.5
    max_turn_rate: float = 1.8
    stop_distance: float = 0.45
    slow_distance: float = 1.2
    front_half_angle: float = math.radians(35)
    heading_gain: float = 2.0
    commit_time: float = 4.0


class WanderController:
    """Picks a far-reaching direction from the scan, holds it for a while, and steers to it.

    Args:
        config: Behaviour settings.
        rng: Breaks ties between equally open directions (seeded for repeatable runs).
    """

    def __init__(self, config: WanderConfig | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.config = config or WanderConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._goal_heading: float | None = None
        self._chosen_at = -math.inf

    def __call__(self, scan: LaserScan, yaw: float) -> tuple[float, float]:
        """Returns (v, omega) for the current scan and yaw (radians, ``map`` frame)."""
        cfg = self.config
        ranges = np.where(np.isfinite(scan.ranges), scan.ranges, scan.range_max)
        rel = (scan.angles + math.pi) % (2 * math.pi) - math.pi
        front = np.abs(rel) <= cfg.front_half_angle
        clearance = float(ranges[front].min()) if front.any() else scan.range_max
        if self._goal_heading is None or scan.stamp - self._chosen_at > cfg.commit_time:
            # Favour long free beams, mildly prefer going straight, randomise ties.
            score = ranges - 0.5 * np.abs(rel) + self.rng.uniform(0, 0.3, size=ranges.shape)
            self._goal_heading = yaw + float(rel[int(np.argmax(score))])
            self._chosen_at = scan.stamp
        error = (self._goal_heading - yaw + math.pi) % (2 * math.pi) - math.pi
        omega = float(np.clip(cfg.heading_gain * error, -cfg.max_turn_rate, cfg.max_turn_rate))
        if clearance < cfg.stop_distance:
            left = ranges[(rel > 0) & (rel < math.pi / 2)].mean()
            right = ranges[(rel < 0) & (rel > -math.pi / 2)].mean()
            self._goal_heading = yaw + (math.pi / 2 if left >= right else -math.pi / 2)
            self._chosen_at = scan.stamp
            return 0.0, cfg.max_turn_rate * (1.0 if left >= right else -1.0)
        speed = cfg.cruise_speed * min(1.0, (clearance - cfg.stop_distance) /
                                       (cfg.slow_distance - cfg.stop_distance))
        speed *= max(0.0, math.cos(error))
        return speed, omega
