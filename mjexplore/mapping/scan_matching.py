"""Scan-to-map matching (correlative search, then a least-squares refinement) and a
localiser that corrects odometry with it.

:func:`match_scan` finds the pose of ``base_scan`` in the ``map`` frame at which a scan's
returns best fit an occupancy grid (:class:`~mjexplore.maps.GridMap`), near a prior pose
(the odometry's):

1. **Correlative search** (Olson, "Real-time correlative scan matching", ICRA 2009): a
   lookup table over the grid, ``exp(-d^2 / (2 sigma^2))`` of each cell's distance ``d`` to
   the nearest occupied cell, scores a pose by the mean of the table at the cells its
   returns fall in. Every pose of a lattice over the search window is scored: translations
   one cell apart, rotations such that the farthest return moves about one cell. Olson's
   multi-resolution search makes it fast and exact: a coarse table holding the maximum of
   each ``coarse_cells``-square block bounds the score of every translation in a block, so
   blocks are refined best bound first and the search stops once no bound beats the best
   score (branch and bound; the answer is the lattice's best pose, as an exhaustive search
   finds it). A small prior term (the squared distance from the prior, ``prior_weight`` at
   the window's edge) breaks ties in favour of odometry.
2. **Confidence** (Olson, section IV): the lattice poses within ``local_cells`` steps of
   the best one, weighted by the scan's likelihood there (the product of its returns'
   table values, each floored), give the match's covariance. A direction along which it
   spreads by a lattice step or more is degenerate (a long featureless corridor, along its
   axis): the estimate keeps the prior along it (solution remapping, as Zhang, Kaess and
   Singh, "On degeneracy of optimization-based state estimation problems", ICRA 2016),
   and its variance is reported as the search window's.
3. **Refinement** below the lattice's step: Gauss-Newton from the best lattice pose on
   each return's distance to the nearest occupied cell, zero inside one (a return lies
   somewhere in the cell the mapper marked, so no point of the cell is preferred), with a
   Huber loss truncated at ``refine_gate_cells``; steps that do not lower the loss are
   halved.

Only the wall cells next to other cells count as occupied: the inside of a thick wall (a
ground-truth map's) would let returns sink into it at no cost.

Returns are the scan's finite ranges (``inf``: no return, NaN: invalid and ``-inf``: too
close carry no position). A scan taken while moving (``LaserScan.time_increment`` != 0,
the LDS-01) should first be de-skewed to its stamp (:func:`deskew_scan`), for matching and
for the mapper alike.

:class:`ScanMatchingLocalizer` keeps the estimate of ``base_link`` in ``map``: ``predict``
(or ``advance``) composes odometry increments, ``correct`` matches a scan against the
current map and takes the match when its score, number of returns and constraints are
good enough.

All poses are (x, y, yaw) in metres and radians, REP-103.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Generic, TypeVar

import cv2
import numba
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap, is_occupied
from mjexplore.robot import TURTLEBOT3_WAFFLE, RobotGeometry
from mjexplore.sim.lidar import LaserScan
from mjexplore.sim.odometry import compose_pose, relative_pose, wrap_angle

log = logging.getLogger(__name__)

ResultT = TypeVar("ResultT")

# A return's likelihood is floored at that of a return three sigma from any wall (Olson's
# tables are bounded below too: a return on nothing is unlikely, not impossible).
LOG_FLOOR = math.exp(-4.5)
# A direction is degenerate when the scan's likelihood spreads along it with a variance
# of this many squared lattice steps (a standard deviation of one step) or more.
DEGENERATE_VARIANCE_STEPS = 1.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class ScanMatcherConfig:
    """Settings of :func:`match_scan` and :class:`ScanMatchingLocalizer`.

    Attributes:
        linear_window: Half-width of the translation search window around the prior, m.
        angular_window: Half-width of the rotation search window, radians.
        sigma: Standard deviation of the lookup table's Gaussian of the distance to the
            nearest occupied cell, metres (the returns' scatter about walls).
        coarse_cells: Side of the blocks of the coarse table, in cells (1: exhaustive).
        prior_weight: Score subtracted at the window's edge (squared-distance prior).
        refine_iterations: Most Gauss-Newton iterations of the refinement (0: none).
        refine_gate_cells: Returns farther than this many cells from any occupied cell
            are left out of the refinement.
        local_cells: Half-width, in lattice steps, of the neighbourhood of the best pose
            whose likelihoods give the covariance.
        min_score: Least correlative score (mean table value, 0..1) to accept a match.
        min_points: Least number of returns to match at all.
        match_gain: Share of an accepted match's correction the localiser applies (1:
            all of it; less averages noisy matches over several scans, a constant-gain
            filter against the odometry).
    """

    linear_window: float = 0.3
    angular_window: float = math.radians(10.0)
    sigma: float = 0.05
    coarse_cells: int = 4
    prior_weight: float = 0.01
    refine_iterations: int = 10
    refine_gate_cells: int = 3
    local_cells: int = 3
    min_score: float = 0.4
    min_points: int = 30
    match_gain: float = 1.0

    def __post_init__(self) -> None:
        if not (self.linear_window >= 0 and 0 <= self.angular_window < math.pi and
                self.sigma > 0 and self.coarse_cells >= 1 and self.prior_weight >= 0 and
                self.refine_iterations >= 0 and self.refine_gate_cells >= 1 and
                self.local_cells >= 1 and 0 <= self.min_score <= 1 and
                self.min_points >= 3 and 0 < self.match_gain <= 1):
            raise UserInputError(
                "scan matcher config needs linear_window >= 0, 0 <= angular_window < pi, "
                "sigma > 0, coarse_cells >= 1, prior_weight >= 0, refine_iterations >= 0, "
                "refine_gate_cells >= 1, local_cells >= 1, min_score in [0, 1], "
                "min_points >= 3 and match_gain in (0, 1].")


@dataclasses.dataclass(frozen=True)
class MatchResult:
    """The outcome of one scan match.

    Attributes:
        pose: Estimated (x, y, yaw) of ``base_scan`` in ``map``; equal to the prior along
            degenerate directions, and the prior itself when the match was not made.
        prior: The prior pose the search was centred on.
        score: Correlative score of the best lattice pose: the mean lookup-table value at
            the returns, 0 (nothing fits) to 1 (every return on an occupied cell).
        points: Number of returns matched.
        inliers: Fraction of them within ``refine_gate_cells`` of an occupied cell at
            the refined pose.
        covariance: 3 x 3 covariance of ``pose`` (m^2, m rad, rad^2): Olson's estimate
            from the likelihoods around the best lattice pose (at least a lattice step's
            quantisation) along constrained directions, the search window's squared
            half-width along degenerate ones.
        degenerate: True when some direction is not constrained by the scan.
        accepted: True when the match is good enough to use (score, points and at least
            one constrained direction).
    """

    pose: np.ndarray
    prior: np.ndarray
    score: float
    points: int
    inliers: float
    covariance: np.ndarray
    degenerate: bool
    accepted: bool


# ---------------------------------------------------------------------------- geometry


def scan_points(scan: LaserScan) -> np.ndarray:
    """The scan's returns (its finite ranges) as (n, 2) points in ``base_scan``, metres.

    A scan taken while moving should be de-skewed first (:func:`deskew_scan`).
    """
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    valid = np.isfinite(ranges)
    angles = np.asarray(scan.angles, dtype=np.float64)[valid]
    return np.column_stack([ranges[valid] * np.cos(angles), ranges[valid] * np.sin(angles)])


def deskew_scan(scan: LaserScan, twist: tuple[float, float] | None = None,
                trajectory: tuple[np.ndarray, np.ndarray] | None = None,
                scan_offset: tuple[float, ...] = TURTLEBOT3_WAFFLE.scan_offset) -> LaserScan:
    """The scan as if every beam were taken from ``base_scan``'s pose at the stamp.

    Beam ``i`` was taken ``i * time_increment`` seconds from the stamp (the LDS-01's are
    before it). The base's motion since then comes from its odometry: a ``trajectory`` of
    samples (interpolated at each beam's instant, as the lidar model itself does), or a
    constant ``twist`` (an arc). Each return is moved into the stamp's ``base_scan`` frame
    (new range and angle); beams without a return keep theirs, turned with the sensor. The
    rays' origins are then all the stamp's, off the true ones by the distance driven
    during the scan.

    Args:
        scan: The scan.
        twist: (forward speed m/s, yaw rate rad/s) of ``base_link`` during the scan.
        trajectory: (times (k,) in seconds, poses (k, 3)) of ``base_link`` in any fixed
            frame (the odometry's: ``kinematics_rows[:, 0]`` and ``[:, 8:11]``), covering
            the scan; used instead of ``twist``.
        scan_offset: (x, y, ...) of ``base_scan`` in ``base_link``, metres.

    Returns:
        The de-skewed scan (``time_increment`` 0); the scan itself when there is no skew.
    """
    if scan.time_increment == 0.0 or (trajectory is None and not np.any(twist)):
        return scan
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    tau = scan.time_increment * np.arange(len(ranges))
    # The base's pose at each beam's instant relative to its pose at the stamp.
    if trajectory is not None:
        times, poses = np.asarray(trajectory[0], float), np.asarray(trajectory[1], float)
        yaw = np.unwrap(poses[:, 2])
        at = [np.interp(scan.stamp + tau, times, col) for col in (poses[:, 0], poses[:, 1], yaw)]
        now = [np.interp(scan.stamp, times, col) for col in (poses[:, 0], poses[:, 1], yaw)]
        c0, s0 = math.cos(now[2]), math.sin(now[2])
        ex, ey = at[0] - now[0], at[1] - now[1]
        dx, dy, dth = c0 * ex + s0 * ey, -s0 * ex + c0 * ey, at[2] - now[2]
    else:
        assert twist is not None  # Without a trajectory or a twist, returned above.
        v, w = float(twist[0]), float(twist[1])
        dth = w * tau
        small = np.abs(dth) < 1e-9
        safe = np.where(small, 1.0, dth)
        dx = np.where(small, v * tau, v * tau * np.sin(safe) / safe)
        dy = np.where(small, 0.0, v * tau * (1.0 - np.cos(safe)) / safe)
    # Then base_scan's, seen from base_scan at the stamp.
    ox, oy = scan_offset[0], scan_offset[1]
    c, s = np.cos(dth), np.sin(dth)
    angles = np.asarray(scan.angles, dtype=np.float64) + dth
    hit = np.isfinite(ranges)
    r = np.where(hit, ranges, 0.0)
    px = dx + (c - 1.0) * ox - s * oy + r * np.cos(angles)
    py = dy + s * ox + (c - 1.0) * oy + r * np.sin(angles)
    new_ranges = np.where(hit, np.hypot(px, py), ranges).astype(np.float32)
    new_angles = np.where(hit, np.arctan2(py, px), angles)
    return dataclasses.replace(scan, ranges=new_ranges, angles=new_angles, time_increment=0.0)


def sensor_pose_of(base_pose: np.ndarray, geometry: RobotGeometry = TURTLEBOT3_WAFFLE
                   ) -> np.ndarray:
    """Pose of ``base_scan`` from that of ``base_link`` (both in one frame)."""
    ox, oy, _ = geometry.scan_offset
    return compose_pose(base_pose, (ox, oy, 0.0))


def base_pose_of(sensor_pose: np.ndarray, geometry: RobotGeometry = TURTLEBOT3_WAFFLE
                 ) -> np.ndarray:
    """Pose of ``base_link`` from that of ``base_scan`` (both in one frame)."""
    ox, oy, _ = geometry.scan_offset
    return compose_pose(sensor_pose, relative_pose((ox, oy, 0.0), (0.0, 0.0, 0.0)))


# ---------------------------------------------------------------------------- kernels


@numba.njit(cache=True, inline="always")
def _score(table, rows, cols, a, di, dj):
    """Sum of the table at the returns of rotation ``a`` shifted by (di, dj) cells."""
    h, w = table.shape
    total = 0.0
    for k in range(rows.shape[1]):
        r = rows[a, k] + di
        c = cols[a, k] + dj
        if 0 <= r < h and 0 <= c < w:
            total += table[r, c]
    return total


@numba.njit(cache=True)
def _branch_and_bound(table, coarse, rows, cols, half, block, pen_lin, pen_ang, a0):
    """Best (rotation, row shift, col shift) of the lattice by the penalised mean score.

    ``rows``/``cols`` (n_angles, n) are the returns' cells at the prior translation,
    ``half`` the window's half-width in cells, ``block`` the coarse block side; the
    penalty is ``pen_lin * (di^2 + dj^2) + pen_ang * (a - a0)^2``. ``coarse[r, c]`` is the
    maximum of ``table`` over rows r..r+block-1 and columns c..c+block-1.

    Returns:
        (a, di, dj, the mean score there without the penalty).
    """
    n_ang = rows.shape[0]
    n = rows.shape[1]
    nb = (2 * half) // block + 1
    bounds = np.empty(n_ang * nb * nb)
    for a in range(n_ang):
        pa = pen_ang * (a - a0) ** 2
        for bi in range(nb):
            lo_i = -half + bi * block
            hi_i = min(lo_i + block - 1, half)
            mi = 0 if lo_i <= 0 <= hi_i else min(lo_i * lo_i, hi_i * hi_i)
            for bj in range(nb):
                lo_j = -half + bj * block
                hi_j = min(lo_j + block - 1, half)
                mj = 0 if lo_j <= 0 <= hi_j else min(lo_j * lo_j, hi_j * hi_j)
                bounds[(a * nb + bi) * nb + bj] = (
                    _score(coarse, rows, cols, a, lo_i, lo_j) / n - pa - pen_lin * (mi + mj))
    order = np.argsort(-bounds)
    best = -np.inf
    best_raw = 0.0
    best_a, best_i, best_j = a0, 0, 0
    for idx in order:
        if bounds[idx] <= best:
            break
        a = idx // (nb * nb)
        bi = (idx // nb) % nb
        bj = idx % nb
        pa = pen_ang * (a - a0) ** 2
        lo_i = -half + bi * block
        lo_j = -half + bj * block
        for di in range(lo_i, min(lo_i + block - 1, half) + 1):
            for dj in range(lo_j, min(lo_j + block - 1, half) + 1):
                raw = _score(table, rows, cols, a, di, dj) / n
                value = raw - pa - pen_lin * (di * di + dj * dj)
                if value > best:
                    best, best_raw, best_a, best_i, best_j = value, raw, a, di, dj
    return best_a, best_i, best_j, best_raw


@numba.njit(cache=True)
def _local_log_likelihoods(log_table, rows, cols, a, di, dj, k):
    """Sums of ``log_table`` at the returns for the lattice poses within ``k`` steps of
    (a, di, dj) in rotation and translation: a (2k+1)^3 array (a, di, dj order), -inf
    where the rotation is outside the lattice."""
    out = np.full((2 * k + 1, 2 * k + 1, 2 * k + 1), -np.inf)
    for ia in range(2 * k + 1):
        aa = a - k + ia
        if not 0 <= aa < rows.shape[0]:
            continue
        for ii in range(2 * k + 1):
            for jj in range(2 * k + 1):
                out[ia, ii, jj] = _score(log_table, rows, cols, aa, di - k + ii, dj - k + jj)
    return out


@numba.njit(cache=True, inline="always")
def accumulate_normal_equations(hess, grad, jac, weight, residual):
    """Adds one weighted residual's terms to the Gauss-Newton system (3 x 3 ``hess``, 3
    ``grad``) of a pose (x, y, yaw); ``jac``: the residual's derivatives, a 3-tuple."""
    for i in range(3):
        grad[i] += weight * jac[i] * residual
        for j in range(3):
            hess[i, j] += weight * jac[i] * jac[j]


@numba.njit(cache=True)
def _normal_equations(occupied, points, x, y, yaw, x0, y0, res, gate, huber, unit):
    """The refinement's loss and Gauss-Newton system at pose (x, y, yaw) of the sensor.

    Each return's residual is its distance (m) to the nearest occupied cell of
    ``occupied`` (whose cell (0, 0) has its lower-left corner at (x0, y0)), 0 inside one,
    ``gate`` cells for returns with none that near (no gradient). The loss is Huber's
    (threshold ``huber``, m); the Jacobian is taken per lattice step (``unit``).

    Returns:
        (loss, J^T W J (3, 3), J^T W r (3,), number of returns within the gate).
    """
    h, w = occupied.shape
    c, s = math.cos(yaw), math.sin(yaw)
    hess = np.zeros((3, 3))
    grad = np.zeros(3)
    loss = 0.0
    inside = 0
    far = gate * res
    for k in range(points.shape[0]):
        ax = c * points[k, 0] - s * points[k, 1]  # The return from the sensor, map axes.
        ay = s * points[k, 0] + c * points[k, 1]
        u = (x + ax - x0) / res
        v = (y + ay - y0) / res
        ci = int(math.floor(v))
        cj = int(math.floor(u))
        r = far
        gx = 0.0
        gy = 0.0
        if 0 <= ci < h and 0 <= cj < w:
            if occupied[ci, cj]:
                r = 0.0
            else:
                best = np.inf
                bx = 0.0
                by = 0.0
                for i in range(max(ci - gate, 0), min(ci + gate + 1, h)):
                    for j in range(max(cj - gate, 0), min(cj + gate + 1, w)):
                        if occupied[i, j]:
                            # Nearest point of cell (i, j)'s square to the return.
                            px = min(max(u, j), j + 1.0)
                            py = min(max(v, i), i + 1.0)
                            d2 = (u - px) ** 2 + (v - py) ** 2
                            if d2 < best:
                                best, bx, by = d2, px, py
                if best <= gate * gate:
                    d = math.sqrt(best)
                    r = d * res
                    if d > 1e-12:
                        gx, gy = (u - bx) / d, (v - by) / d
        if r < far:
            inside += 1
        loss += 0.5 * r * r if r <= huber else huber * (r - 0.5 * huber)
        if gx == 0.0 and gy == 0.0:
            continue
        wgt = 1.0 if r <= huber else huber / r
        jac = (gx * unit[0], gy * unit[1], (gy * ax - gx * ay) * unit[2])
        accumulate_normal_equations(hess, grad, jac, wgt, r)
    return loss, hess, grad, inside


# ---------------------------------------------------------------------------- matcher


class _Crop:
    """The part of a grid a match can reach, with its lookup tables."""

    def __init__(self, grid: GridMap, centre: np.ndarray, reach: float,
                 config: ScanMatcherConfig) -> None:
        res = grid.resolution
        rows, cols = grid.shape
        c0, r0 = np.floor((centre - np.asarray(grid.origin[:2])) / res).astype(int)
        k = int(math.ceil(reach / res))
        self.r0, self.c0 = max(r0 - k, 0), max(c0 - k, 0)
        r1, c1 = min(r0 + k + 1, rows), min(c0 + k + 1, cols)
        self.res = res
        self.origin = (grid.origin[0] + self.c0 * res, grid.origin[1] + self.r0 * res)
        if r1 <= self.r0 or c1 <= self.c0:
            self.occupied = np.zeros((1, 1), np.bool_)
        else:
            occupied = is_occupied(grid.data[self.r0:r1, self.c0:c1])
            inner = cv2.erode(occupied.astype(np.uint8), np.ones((3, 3), np.uint8),
                              borderType=cv2.BORDER_CONSTANT, borderValue=1)
            self.occupied = occupied & (inner == 0)
        free = (~self.occupied).astype(np.uint8)
        if self.occupied.any():
            dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_5)
        else:
            dist = np.full(free.shape, np.inf, np.float32)
        self.table = np.exp(-0.5 * (dist * (res / config.sigma)) ** 2).astype(np.float32)
        self.log_table = np.log(np.maximum(self.table, LOG_FLOOR))
        block = config.coarse_cells
        self.coarse = cv2.dilate(self.table, np.ones((block, block), np.uint8), anchor=(0, 0),
                                 borderType=cv2.BORDER_CONSTANT, borderValue=0.0)


def match_scan(points: np.ndarray, grid: GridMap, prior: np.ndarray,
               config: ScanMatcherConfig | None = None) -> MatchResult:
    """Matches returns against an occupancy grid near a prior pose.

    Args:
        points: (n, 2) returns in ``base_scan``, metres (see :func:`scan_points`).
        grid: The map (occupied cells are what returns should fall on).
        prior: (x, y, yaw) of ``base_scan`` in ``map`` to search around (odometry's).
        config: Search settings.

    Returns:
        The match; ``accepted`` says whether to use it.
    """
    cfg = config or ScanMatcherConfig()
    prior = np.array(prior, dtype=float)
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    n = len(points)
    res = grid.resolution
    ranges = np.hypot(points[:, 0], points[:, 1])
    r_far = max(float(ranges.max()) if n else 0.0, 4 * res)
    # The lattice: translations one cell apart, rotations such that the farthest return
    # moves about one cell.
    step = math.acos(max(1.0 - res * res / (2.0 * r_far * r_far), -1.0))
    half = int(math.ceil(cfg.linear_window / res))
    half_a = int(math.ceil(cfg.angular_window / step))
    unit = np.array([res, res, step])  # One lattice step per axis.
    window = np.diag(np.array([half, half, half_a], dtype=float) ** 2) * np.outer(unit, unit)
    crop = _Crop(grid, prior[:2], r_far + cfg.linear_window + (cfg.local_cells + 2) * res, cfg)
    if n < cfg.min_points or not crop.occupied.any():
        return MatchResult(prior.copy(), prior.copy(), 0.0, n, 0.0, window, True, False)
    yaws = prior[2] + step * np.arange(-half_a, half_a + 1)
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]  # The returns at every rotation:
    cols = np.floor((c * points[:, 0] - s * points[:, 1] + prior[0] - crop.origin[0]) /
                    res).astype(np.int64)
    rows = np.floor((s * points[:, 0] + c * points[:, 1] + prior[1] - crop.origin[1]) /
                    res).astype(np.int64)
    pen_lin = cfg.prior_weight / max(half, 1) ** 2
    pen_ang = cfg.prior_weight / max(half_a, 1) ** 2
    a, di, dj, score = _branch_and_bound(crop.table, crop.coarse, rows, cols, half,
                                               cfg.coarse_cells, pen_lin, pen_ang, half_a)
    lattice = np.array([prior[0] + dj * res, prior[1] + di * res, yaws[a]])
    # Olson's covariance: the lattice poses around the best one weighted by the scan's
    # likelihood (the product of the returns' table values), in lattice steps.
    k = cfg.local_cells
    loglik = _local_log_likelihoods(crop.log_table, rows, cols, a, di, dj, k)
    weight = np.exp(loglik - loglik.max())
    offsets = np.stack(np.meshgrid(*(np.arange(-k, k + 1.0),) * 3, indexing="ij"), axis=-1)
    offsets = offsets[..., [2, 1, 0]].reshape(-1, 3)  # (dj, di, da): x, y, yaw steps.
    weight = weight.reshape(-1) / weight.sum()
    mean = weight @ offsets
    cov_steps = (offsets * weight[:, None]).T @ offsets - np.outer(mean, mean)
    cov_steps += np.eye(3) / 12.0  # A lattice step's own quantisation.
    eigval, eigvec = np.linalg.eigh(cov_steps)
    keep = eigval < DEGENERATE_VARIANCE_STEPS
    pose, inliers = _refine(points, crop, lattice, unit, cfg)
    # Along directions the scan does not constrain, the prior stays (solution remapping).
    projector = (eigvec[:, keep] @ eigvec[:, keep].T) * np.outer(unit, 1.0 / unit)
    delta = pose - prior
    delta[2] = wrap_angle(delta[2])
    estimate = prior + projector @ delta
    estimate[2] = wrap_angle(estimate[2])
    free_dirs = eigvec[:, ~keep]
    window_steps = window / np.outer(unit, unit)
    cov_steps = ((eigvec[:, keep] * eigval[keep]) @ eigvec[:, keep].T +
                 free_dirs @ (free_dirs.T @ window_steps @ free_dirs) @ free_dirs.T)
    accepted = bool(score >= cfg.min_score and keep.any())
    return MatchResult(estimate, prior, float(score), n, inliers,
                       cov_steps * np.outer(unit, unit), bool(not keep.all()), accepted)


def _refine(points: np.ndarray, crop: _Crop, pose: np.ndarray, unit: np.ndarray,
            cfg: ScanMatcherConfig) -> tuple[np.ndarray, float]:
    """Gauss-Newton from the lattice's best pose on the returns' distances to the nearest
    occupied cell (Huber loss, truncated at ``refine_gate_cells``), halving steps that do
    not lower the loss; directions with no information are left alone.

    Returns:
        The refined pose and the fraction of returns within ``refine_gate_cells`` of an
        occupied cell there.
    """
    def system(p: np.ndarray):
        return _normal_equations(crop.occupied, points, p[0], p[1], p[2], crop.origin[0],
                                 crop.origin[1], crop.res, cfg.refine_gate_cells, cfg.sigma,
                                 unit)

    loss, hessian, grad, inside = system(pose)
    for _ in range(cfg.refine_iterations):
        eigval, eigvec = np.linalg.eigh(hessian)
        keep = eigval > 1e-9 * max(eigval.max(), 1e-12)
        if not keep.any():
            break
        step = -(eigvec[:, keep] / eigval[keep]) @ (eigvec[:, keep].T @ grad) * unit
        for _ in range(4):
            trial = pose + step
            new = system(trial)
            if new[0] < loss:
                break
            step = step / 2
        else:
            break
        pose = trial
        loss, hessian, grad, inside = new
        if np.all(np.abs(step) < 1e-3 * unit):
            break
    pose = pose.copy()
    pose[2] = wrap_angle(pose[2])
    return pose, inside / max(len(points), 1)


# ---------------------------------------------------------------------------- localiser


class LocalizerBase(Generic[ResultT]):
    """What the localisers share: the pose of ``base_link`` in ``map`` moved by odometry
    increments; each subclass corrects it with scans in its own way, and ``ResultT`` is
    the type of its corrections' outcomes.

    Attributes:
        geometry: The robot (where ``base_scan`` sits on ``base_link``).
        last_match: The outcome of the latest correction (None before any).
        matches: Number of accepted corrections.
        rejections: Number of corrections not taken.
    """

    geometry: RobotGeometry
    last_match: ResultT | None

    def reset(self, pose: tuple[float, float, float] | np.ndarray,
              odom_pose: tuple[float, float, float] | np.ndarray | None = None) -> None:
        """Restarts at ``pose`` (``map``); ``odom_pose`` is the odometry's reading there."""
        self._pose = np.array(pose, dtype=float)
        self._last_odom = None if odom_pose is None else np.array(odom_pose, dtype=float)
        self._last_stamp: float | None = None
        self.last_match = None
        self.matches = 0
        self.rejections = 0

    @property
    def pose(self) -> np.ndarray:
        """Estimated (x, y, yaw) of ``base_link`` in ``map``."""
        return self._pose.copy()

    @property
    def sensor_pose(self) -> np.ndarray:
        """Estimated (x, y, yaw) of ``base_scan`` in ``map`` (for the mapper)."""
        return sensor_pose_of(self._pose, self.geometry)

    def predict(self, odom_delta: tuple[float, float, float] | np.ndarray,
                dt: float = 0.0) -> None:
        """Moves the estimate by an odometry increment (x, y, yaw) given in the previous
        ``base_link`` frame (``relative_pose(odom_before, odom_after)``), taken over ``dt``
        seconds (not used here; the fused localiser's gyro bias needs it)."""
        del dt
        self._pose = compose_pose(self._pose, odom_delta)

    def advance(self, odom_pose: tuple[float, float, float] | np.ndarray,
                stamp: float | None = None) -> None:
        """Moves the estimate by the odometry's change since the last call (or reset with
        ``odom_pose``); the first call only records ``odom_pose`` (``odom`` frame).
        ``stamp``: the reading's simulated time in seconds (the increment's duration is
        taken between two stamped calls, else 0)."""
        odom_pose = np.array(odom_pose, dtype=float)
        dt = 0.0 if stamp is None or self._last_stamp is None else stamp - self._last_stamp
        if self._last_odom is not None:
            self.predict(relative_pose(self._last_odom, odom_pose), max(dt, 0.0))
        self._last_odom = odom_pose
        if stamp is not None:
            self._last_stamp = float(stamp)

    def map_to_odom(self, odom_pose: tuple[float, float, float] | np.ndarray) -> np.ndarray:
        """The ``map -> odom`` transform (x, y, yaw) that puts ``odom_pose`` (``base_link``
        in ``odom``) at the estimate, as a ROS localiser publishes it."""
        return compose_pose(self._pose, relative_pose(odom_pose, (0.0, 0.0, 0.0)))


class ScanMatchingLocalizer(LocalizerBase[MatchResult]):
    """The pose of ``base_link`` in ``map``: odometry increments corrected by scan matches.

    Args:
        pose: Initial (x, y, yaw) of ``base_link`` in ``map``.
        odom_pose: The odometry's reading (``base_link`` in ``odom``) at ``pose``, from
            which :meth:`advance` counts; None: from its first call.
        config: Matcher settings.
        geometry: The robot (where ``base_scan`` sits on ``base_link``).

    Attributes:
        last_match: The result of the latest :meth:`correct` (None before any).
        matches: Number of accepted matches.
        rejections: Number of matches not taken.
    """

    def __init__(self, pose: tuple[float, float, float] | np.ndarray,
                 odom_pose: tuple[float, float, float] | np.ndarray | None = None,
                 config: ScanMatcherConfig | None = None,
                 geometry: RobotGeometry = TURTLEBOT3_WAFFLE) -> None:
        self.config = config or ScanMatcherConfig()
        self.geometry = geometry
        self.reset(pose, odom_pose)

    def correct(self, scan: LaserScan, grid: GridMap) -> MatchResult:
        """Matches ``scan`` (taken at the estimate's time) against ``grid`` and takes the
        result when it is accepted.

        Args:
            scan: The scan, de-skewed when taken while moving (:func:`deskew_scan`); its
                ``pose`` (the ground truth) is not used.
            grid: The map to match against (e.g. the mapper's, built with the estimates).

        Returns:
            The match.
        """
        result = match_scan(scan_points(scan), grid, self.sensor_pose, self.config)
        self.last_match = result
        if result.accepted:
            delta = relative_pose(self._pose, base_pose_of(result.pose, self.geometry))
            self._pose = compose_pose(self._pose, delta * self.config.match_gain)
            self.matches += 1
        else:
            self.rejections += 1
        return result
