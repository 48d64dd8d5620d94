"""2D occupancy grids in the ``nav_msgs/OccupancyGrid`` convention.

Cell values: -1 unknown, 0 free, 100 occupied (values in between are occupancy
probabilities in percent). Row 0 is the lowest ``y``; column 0 the lowest ``x``. The cell
``(row, col)`` covers ``[x0 + col * res, x0 + (col + 1) * res) x [y0 + row * res, ...)`` in the
``map`` frame, where ``(x0, y0)`` is the origin (the lower-left corner of cell (0, 0)).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numba
import numpy as np

UNKNOWN = -1
FREE = 0
OCCUPIED = 100


def is_free(values: np.ndarray) -> np.ndarray:
    """Cell values known to be free (occupancy below 50 %)."""
    return (values >= 0) & (values < 50)


def is_occupied(values: np.ndarray) -> np.ndarray:
    """Cell values known to be occupied (occupancy 50 % or more)."""
    return values >= 50


def is_known(values: np.ndarray) -> np.ndarray:
    """Cell values that are not unknown."""
    return values >= 0


def window_counts(mask: np.ndarray, cells: np.ndarray, half: int) -> np.ndarray:
    """True cells of ``mask`` in the (2 half + 1)-cell square around each (row, col) of
    ``cells`` (k, 2), the square clipped to the grid; one integral image for all."""
    integral = cv2.integral(mask.astype(np.uint8), sdepth=cv2.CV_32S)  # (rows + 1, cols + 1)
    rows, cols = mask.shape
    cells = np.asarray(cells).reshape(-1, 2)
    r0 = np.clip(cells[:, 0] - half, 0, rows)
    r1 = np.clip(cells[:, 0] + half + 1, 0, rows)
    c0 = np.clip(cells[:, 1] - half, 0, cols)
    c1 = np.clip(cells[:, 1] + half + 1, 0, cols)
    return integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0]


@dataclasses.dataclass(frozen=True, eq=False)
class GridMap:
    """An occupancy grid in the ``map`` frame.

    Attributes:
        data: int8 array of shape (rows, cols): -1 unknown, 0..100 occupancy in percent.
        resolution: Cell side in metres.
        origin: (x, y, yaw) of the lower-left corner of cell (0, 0) in the ``map`` frame,
            metres and radians. Only yaw 0 is supported.
    """

    data: np.ndarray
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.data.ndim != 2 or self.data.dtype != np.int8:
            raise ValueError("GridMap.data must be a 2D int8 array")
        if not self.resolution > 0:
            raise ValueError("GridMap.resolution must be positive")
        if self.origin[2] != 0.0:
            raise ValueError("GridMap supports only origin yaw 0")

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape

    @property
    def size_m(self) -> tuple[float, float]:
        """(width along x, height along y) in metres."""
        return self.data.shape[1] * self.resolution, self.data.shape[0] * self.resolution

    @property
    def free(self) -> np.ndarray:
        """Boolean mask of cells known to be free (occupancy below 50 %)."""
        return is_free(self.data)

    @property
    def occupied(self) -> np.ndarray:
        """Boolean mask of cells known to be occupied (occupancy 50 % or more)."""
        return is_occupied(self.data)

    @property
    def known(self) -> np.ndarray:
        return is_known(self.data)

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Maps points (..., 2) in metres to integer (row, col) indices (may be out of bounds)."""
        xy = np.asarray(xy, dtype=float)
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return np.stack([row, col], axis=-1)

    def cell_to_world(self, rc: np.ndarray) -> np.ndarray:
        """Maps (..., 2) integer (row, col) indices to cell-centre points in metres."""
        rc = np.asarray(rc, dtype=float)
        x = self.origin[0] + (rc[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (rc[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def in_bounds(self, rc: np.ndarray) -> np.ndarray:
        rc = np.asarray(rc)
        return (rc[..., 0] >= 0) & (rc[..., 0] < self.shape[0]) & (rc[..., 1] >= 0) & (
            rc[..., 1] < self.shape[1]
        )

    def value_at(self, xy: np.ndarray) -> np.ndarray:
        """Cell values at points (..., 2) in metres; -1 outside the grid."""
        rc = self.world_to_cell(xy)
        inside = self.in_bounds(rc)
        out = np.full(rc.shape[:-1], UNKNOWN, dtype=np.int8)
        out[inside] = self.data[rc[inside][:, 0], rc[inside][:, 1]]
        return out

    def equals(self, other: GridMap) -> bool:
        return (
            self.data.shape == other.data.shape
            and bool(np.array_equal(self.data, other.data))
            and self.resolution == other.resolution
            and tuple(self.origin) == tuple(other.origin)
        )


@numba.njit(cache=True, inline="always")
def traversal_start(x0, y0, dx, dy):
    """Set-up of an Amanatides-Woo walk over the cells a ray from (x0, y0) along the unit
    direction (dx, dy) crosses, all in cell units (x along columns, y along rows).

    Returns:
        The start cell (cx, cy), the cell step per axis (+-1), the ray parameter at the
        first cell boundary per axis, and the parameter across one cell per axis.
    """
    cx = int(math.floor(x0))
    cy = int(math.floor(y0))
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    t_max_x = ((cx + (step_x > 0)) - x0) / dx if dx != 0 else np.inf
    t_max_y = ((cy + (step_y > 0)) - y0) / dy if dy != 0 else np.inf
    t_dx = abs(1.0 / dx) if dx != 0 else np.inf
    t_dy = abs(1.0 / dy) if dy != 0 else np.inf
    return cx, cy, step_x, step_y, t_max_x, t_max_y, t_dx, t_dy
