"""A reactive wandering controller: drive toward open, unvisited space; turn from walls.

It needs no map, only the latest scan and the robot's pose (to count visits on a coarse
grid); the demo and the simulator benchmark use it to drive the robot through a scene in
closed loop.
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
        visit_cell: Side of the visit-count grid cells, metres.
        visit_weight: Score penalty per earlier visit of the cell a beam points at.
        lookahead: Distance along a beam (capped by its range) whose cell is scored, m.
        half_width: Half-width of the corridor the robot needs to drive along a beam, m.
    """

    cruise_speed: float = 0.5
    max_turn_rate: float = 1.8
    stop_distance: float = 0.45
    slow_distance: float = 1.2
    front_half_angle: float = math.radians(35)
    heading_gain: float = 2.0
    commit_time: float = 4.0
    visit_cell: float = 1.0
    visit_weight: float = 0.05
    lookahead: float = 3.0
    half_width: float = 0.3


def passable_distance(scan: LaserScan, half_width: float) -> np.ndarray:
    """How far the robot can drive along each beam direction before its corridor is blocked.

    A scan point blocks direction ``theta`` if it lies ahead along ``theta`` and less than
    ``half_width`` to either side of the line; the result is the nearest such point's
    distance along the line (``range_max`` if none), one value per beam, in metres.
    """
    hit = np.isfinite(scan.ranges)
    px = scan.ranges[hit] * np.cos(scan.angles[hit])
    py = scan.ranges[hit] * np.sin(scan.angles[hit])
    c, s = np.cos(scan.angles)[:, None], np.sin(scan.angles)[:, None]
    along = px[None] * c + py[None] * s
    across = np.abs(py[None] * c - px[None] * s)
    blocking = np.where((across < half_width) & (along > 0), along, scan.range_max)
    return blocking.min(axis=1, initial=scan.range_max)


class WanderController:
    """Picks a far-reaching direction from the scan, holds it for a while, and steers to it.

    Args:
        config: Behaviour settings.
        rng: Breaks ties between equally open directions (seeded for repeatable runs).
    """

    _GRID = 1024  # Visit grid side in cells, centred on the first pose.

    def __init__(self, config: WanderConfig | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.config = config or WanderConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._goal_heading: float | None = None
        self._chosen_at = -math.inf
        self._visits = np.zeros((self._GRID, self._GRID), np.int32)
        self._centre: np.ndarray | None = None

    def _cells(self, xy: np.ndarray) -> np.ndarray:
        idx = np.floor((xy - self._centre) / self.config.visit_cell).astype(int) + self._GRID // 2
        return np.clip(idx, 0, self._GRID - 1)

    def __call__(self, scan: LaserScan, pose: np.ndarray) -> tuple[float, float]:
        """Returns (v, omega) for the current scan and pose (x, y, yaw) in ``map``."""
        cfg = self.config
        x, y, yaw = (float(v) for v in pose)
        if self._centre is None:
            self._centre = np.array([x, y])
        here = self._cells(np.array([x, y]))
        self._visits[here[1], here[0]] += 1
        ranges = np.nan_to_num(scan.ranges, posinf=scan.range_max, neginf=0.0)  # -inf: close.
        rel = (scan.angles + math.pi) % (2 * math.pi) - math.pi
        front = np.abs(rel) <= cfg.front_half_angle
        clearance = float(ranges[front].min()) if front.any() else scan.range_max
        if self._goal_heading is None or scan.stamp - self._chosen_at > cfg.commit_time:
            # Favour long free beams toward rarely visited cells, mildly prefer going
            # straight, randomise ties.
            reach = np.minimum(passable_distance(scan, cfg.half_width), cfg.lookahead)
            heading = yaw + scan.angles
            ends = self._cells(np.column_stack([x + reach * np.cos(heading),
                                                y + reach * np.sin(heading)]))
            visits = self._visits[ends[:, 1], ends[:, 0]]
            score = (reach - 0.5 * np.abs(rel) - cfg.visit_weight * visits +
                     self.rng.uniform(0, 0.3, size=ranges.shape))
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
