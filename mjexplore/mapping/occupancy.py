"""Log-odds occupancy-grid mapping of 2D lidar scans.

Each beam is traced through the grid from the sensor cell (Amanatides-Woo traversal, in
numba): the cells it crosses get the "miss" update, the cell of its return the "hit"
update; a beam with no return (``inf``) clears cells up to ``range_max``. Within one
scan a cell that is the return of any beam gets only the hit update, so grazing beams do
not erode walls. Only the cells a scan touches are updated, and :meth:`integrate` reports
those whose trinary state (free / occupied / unknown) changed.

The grid has a fixed extent, given at construction (usually the scene's bounds).
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap, traversal_start
from mjexplore.sim.lidar import LaserScan


@dataclasses.dataclass(frozen=True, kw_only=True)
class MapperConfig:
    """Log-odds sensor model and thresholds.

    The defaults are the usual ones of ROS mappers (hit p = 0.7, miss p = 0.4, clamped),
    with the trinary view "any evidence": a cell is occupied once its log-odds is above
    ``occupied_above`` (0), free once below ``free_below`` (0), and unknown only while no
    beam has touched it. Tighter thresholds would turn cells that flip between hit and miss
    under range noise (wall surfaces) back into unknown space, i.e. into false frontiers.

    Attributes:
        resolution: Cell side in metres.
        log_odds_hit: Added to a cell where a beam returns.
        log_odds_miss: Added to a cell a beam passes through.
        log_odds_min: Lower clamp (keeps cells able to change).
        log_odds_max: Upper clamp.
        occupied_above: Log-odds above which a cell is occupied.
        free_below: Log-odds below which a cell is free.
    """

    resolution: float = 0.05
    log_odds_hit: float = 0.85
    log_odds_miss: float = -0.4
    log_odds_min: float = -2.0
    log_odds_max: float = 3.5
    occupied_above: float = 0.0
    free_below: float = 0.0

    def __post_init__(self) -> None:
        if not (self.log_odds_hit > 0 > self.log_odds_miss and
                self.log_odds_min <= self.free_below <= 0 <= self.occupied_above <=
                self.log_odds_max and self.resolution > 0):
            raise UserInputError("mapper config needs hit > 0 > miss, min <= free_below <= 0 <= "
                                 "occupied_above <= max, and resolution > 0.")


@numba.njit(cache=True)
def _state_of(l: float, occ_above: float, free_below: float) -> int:
    if l > occ_above:
        return OCCUPIED
    if l < free_below:
        return FREE
    return UNKNOWN


@numba.njit(cache=True)
def _integrate_scan(logodds, state, stamp, old_state, touched, scan_id, x0, y0, angles,
                    ranges, range_max, l_hit, l_miss, l_min, l_max, occ_above, free_below,
                    changed):
    """Updates ``logodds``/``state`` in place; returns the number of changed cells.

    ``x0, y0`` are the sensor position and ``angles`` the beam directions, all in cell
    units of the grid (x along columns, y along rows). ``stamp``, ``old_state`` and
    ``touched`` are scratch arrays of one entry per cell; ``changed`` receives flat indices.
    """
    rows, cols = logodds.shape
    n_touched = 0
    is_hit = np.zeros(len(ranges), np.bool_)
    end_r = np.empty(len(ranges), np.int64)
    end_c = np.empty(len(ranges), np.int64)
    cos_a, sin_a = np.cos(angles), np.sin(angles)  # Computed once for both passes.
    # Pass 1: the return cells, marked so that pass 2 leaves them alone.
    for i in range(len(ranges)):
        r = ranges[i]
        # A return lies on the surface of the cell it hit: step a hair past it so that a
        # surface on a cell boundary maps into the wall cell, not the free one before it.
        length = r + 1e-3 if np.isfinite(r) else range_max
        ex = x0 + length * cos_a[i]
        ey = y0 + length * sin_a[i]
        end_c[i] = int(math.floor(ex))
        end_r[i] = int(math.floor(ey))
        if np.isfinite(r) and 0 <= end_r[i] < rows and 0 <= end_c[i] < cols:
            is_hit[i] = True
            k = end_r[i] * cols + end_c[i]
            if stamp[k] != scan_id and stamp[k] != -scan_id:  # First touch in this scan.
                old_state[k] = state.flat[k]
                touched[n_touched] = k
                n_touched += 1
            stamp[k] = -scan_id  # Negative stamp: a return cell in this scan.
    # Pass 2: misses along each beam (Amanatides-Woo), skipping return cells.
    for i in range(len(ranges)):
        if np.isnan(ranges[i]) or ranges[i] < 0:
            continue  # Too close (-inf) or invalid: says nothing about the space beyond.
        cx, cy, step_x, step_y, t_max_x, t_max_y, t_dx, t_dy = traversal_start(
            x0, y0, cos_a[i], sin_a[i])
        ec, er = end_c[i], end_r[i]  # Locals: the loop's stores could alias the arrays.
        while True:
            if cx == ec and cy == er:
                break
            if not (0 <= cy < rows and 0 <= cx < cols):
                break
            k = cy * cols + cx
            # A cell at the lower clamp stays there and keeps its state: a miss on it is a
            # no-op, so it is not even listed as touched (most cells near the robot).
            if logodds.flat[k] > l_min and stamp[k] != -scan_id:
                if stamp[k] != scan_id:
                    stamp[k] = scan_id
                    old_state[k] = state.flat[k]
                    touched[n_touched] = k
                    n_touched += 1
                l = logodds.flat[k] + l_miss
                logodds.flat[k] = l if l > l_min else l_min
            if t_max_x < t_max_y:
                cx += step_x
                t_max_x += t_dx
            else:
                cy += step_y
                t_max_y += t_dy
        if (not is_hit[i] and 0 <= cy < rows and 0 <= cx < cols
                and stamp[cy * cols + cx] != -scan_id):
            k = cy * cols + cx  # The last cell of a beam with no return is free space too.
            if stamp[k] != scan_id:
                stamp[k] = scan_id
                old_state[k] = state.flat[k]
                touched[n_touched] = k
                n_touched += 1
            l = logodds.flat[k] + l_miss
            logodds.flat[k] = l if l > l_min else l_min
    for i in range(len(ranges)):
        if is_hit[i]:
            k = end_r[i] * cols + end_c[i]
            if stamp[k] == -scan_id:
                stamp[k] = scan_id  # Apply the hit once per cell and scan.
                l = logodds.flat[k] + l_hit
                logodds.flat[k] = l if l < l_max else l_max
    n_changed = 0
    for j in range(n_touched):
        k = touched[j]
        s = _state_of(logodds.flat[k], occ_above, free_below)
        state.flat[k] = s
        if s != old_state[k]:
            changed[n_changed] = k
            n_changed += 1
    return n_changed


class OccupancyMapper:
    """An occupancy grid built from scans, with a fixed extent.

    Args:
        shape: (rows, cols) of the grid.
        origin: (x, y) of the lower-left corner of cell (0, 0) in the ``map`` frame, metres.
        config: Sensor model and resolution.
    """

    def __init__(self, shape: tuple[int, int], origin: tuple[float, float],
                 config: MapperConfig | None = None) -> None:
        self.config = config or MapperConfig()
        self.origin = (float(origin[0]), float(origin[1]))
        self.logodds = np.zeros(shape, np.float32)
        self.state = np.full(shape, UNKNOWN, np.int8)
        self._stamp = np.zeros(shape[0] * shape[1], np.int64)
        self._old = np.zeros(shape[0] * shape[1], np.int8)
        self._scans = 0
        self._touched = np.empty(shape[0] * shape[1], np.int64)
        self._changed = np.empty(shape[0] * shape[1], np.int64)

    @classmethod
    def like(cls, grid: GridMap, config: MapperConfig | None = None) -> OccupancyMapper:
        """A mapper covering the same cells as ``grid`` (e.g. the ground truth)."""
        config = config or MapperConfig(resolution=grid.resolution)
        if not math.isclose(config.resolution, grid.resolution):
            raise UserInputError("mapper resolution differs from the grid it should cover.")
        return cls(grid.shape, grid.origin[:2], config)

    @property
    def grid(self) -> GridMap:
        """The trinary map (a view: it changes as scans are integrated)."""
        return GridMap(self.state, self.config.resolution, (*self.origin, 0.0))

    def integrate(self, scan: LaserScan, sensor_pose: np.ndarray | None = None) -> np.ndarray:
        """Integrates one scan taken from ``sensor_pose`` (default: the scan's own pose).

        Args:
            scan: The scan.
            sensor_pose: (x, y, yaw) of ``base_scan`` in the ``map`` frame; pass an
                odometry-based pose to map with odometry instead of the ground truth.

        Returns:
            (k, 2) int array of the (row, col) cells whose trinary state changed.
        """
        cfg = self.config
        x, y, yaw = scan.pose if sensor_pose is None else sensor_pose
        self._scans += 1
        res = cfg.resolution
        n = _integrate_scan(
            self.logodds, self.state, self._stamp, self._old, self._touched, self._scans,
            (x - self.origin[0]) / res, (y - self.origin[1]) / res,
            (scan.angles + yaw).astype(np.float64), scan.ranges.astype(np.float64) / res,
            scan.range_max / res, cfg.log_odds_hit, cfg.log_odds_miss, cfg.log_odds_min,
            cfg.log_odds_max, cfg.occupied_above, cfg.free_below, self._changed)
        flat = self._changed[:n]
        return np.column_stack([flat // self.state.shape[1], flat % self.state.shape[1]])
