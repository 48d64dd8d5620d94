"""A localiser that fuses wheel odometry with scans matched against a likelihood field.

:class:`FusedLocalizer` keeps the estimate of ``base_link`` in ``map`` and its 3 x 3
covariance, as an extended Kalman filter in information form whose update is an
optimisation (as Cartographer's local scan matcher and Hector SLAM do):

* **Prediction**: each odometry increment (x, y, yaw in the previous ``base_link``) is
  composed onto the estimate, and its covariance (an odometry model in the spirit of
  Thrun et al.'s, ``odom_*`` below: errors growing with the distance driven and the
  angle turned) is propagated with the composition's Jacobians.
* **Likelihood field** (Thrun, Burgard and Fox, "Probabilistic Robotics", section 6.4;
  AMCL's ``likelihood_field`` model): a "distance to the nearest wall" for every cell near
  the robot, bilinearly interpolated. By default (``field='returns'``) the localiser
  keeps its own map for it, a density of the returns placed at the estimates (each
  weighted by its precision: the LDS-01's far returns count less): a wall is where most
  returns fell (:meth:`LikelihoodField.from_density`). The occupancy grid's walls
  (``field='map'``: log-odds above ``occupied_logodds``) are a band as thick as the
  returns' scatter, which a scan can slide in at no cost; matching against it drifts
  more (pose RMSE 0.50 m against 0.17 m replaying a maze exploration's LDS-01 scans
  with ``typical`` odometry).
* **Update**: Gauss-Newton (with step halving) on the returns' squared distances to the
  walls, each weighted by its own range noise (``range_noise_*``: the LDS-01's 3.5 % of
  the range makes far returns weak), returns beyond ``max_distance`` being outliers at a
  constant cost, plus the prediction's Mahalanobis term as a prior. The scan's
  information is divided by ``scan_correlation`` (its returns' errors are not independent:
  the map they are compared with was built from the same kind of scans). The inverse of
  the final Hessian is the new covariance. A direction the scan does not constrain (a
  corridor's axis) keeps the prior's estimate and variance by construction.
* **Odometry self-calibration** (an augmented-state EKF, as Martinelli, Tomatis and
  Siegwart, "Simultaneous localization and odometry self calibration for mobile robots",
  Autonomous Robots 22, 2007): the state also holds the odometry's systematic errors in
  Borenstein and Feng's classes (:mod:`mjexplore.sim.odometry`): a distance scale, a
  rotation scale (the track width's error) and a heading change per metre driven (the
  wheel radii's ratio). Each increment is corrected by them before it is composed, and
  every accepted match refines them through their correlation with the pose. Uncorrected,
  a 1.5 % track width error turns the estimate a little on every turn, the map it
  deposits turns with it, and the drift never comes back: nearest on
  ``loop_with_corridor`` with the LDS-01 (seed 2) ended 16 degrees and 3.4 m off.
* Returns near the range limit are biased short (the noise took the others past it):
  those within ``truncation_sigmas`` standard deviations of it are left out.
* **Rejection**: too few returns, too few of them near a wall, or a correction the
  prediction's covariance makes implausible (``gate_sigmas``) leave the prediction alone.
  When the prediction's covariance has grown beyond the field's reach (after rejections),
  Olson's correlative search (:func:`~mjexplore.mapping.scan_matching.match_scan`) first
  finds the basin to start from.

All poses are (x, y, yaw) in metres and radians, REP-103; covariances in m^2, m rad and
rad^2.
"""

from __future__ import annotations

import dataclasses
import math
import types

import cv2
import numba
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.mapping.scan_matching import (
    LocalizerBase,
    ScanMatcherConfig,
    accumulate_normal_equations,
    base_pose_of,
    match_scan,
    scan_points,
)
from mjexplore.maps import GridMap, is_occupied
from mjexplore.robot import TURTLEBOT3_WAFFLE, RobotGeometry
from mjexplore.sim.lidar import LaserScan, range_noise_std
from mjexplore.sim.odometry import HEADINGS, compose_pose, wrap_angle

# The settings of a gyro heading (turtlebot3_node's use_imu). Its odometry model: no slip in
# turns, so a rotation is off by little beyond the scale error the state estimates (1 %
# per radian left as margin for its drift); no heading change per metre; the bias (per
# second) is estimated instead, with a prior twice the ``typical`` gyro's
# (:mod:`mjexplore.sim.odometry`). And walls enter the field after a third of the returns
# the wheels' setting waits for: below ``min_density`` a wall's likelihood is scaled by how
# often it was seen, which, while new ground is mapped, holds the estimate back. Down a
# corridor with pillars and exact odometry (LDS-01) it lags 0.35 % of the distance at 1.5
# and 0.19 % at 0.5 (0.07 % and 0.045 % with the returns deposited at the true poses: the
# loop of mapping and matching makes most of it). For the same reason a scan's information
# counts a quarter, not a half (``scan_correlation`` 4): the density it is matched against
# was built by the estimates it corrects, and the gyro's prediction is the better one. Both
# measured better in episodes (the README's localisation section); with the wheels'
# heading, whose errors are larger, min_density 0.5 measured no better, so their defaults
# stay.
GYRO_HEADING = types.MappingProxyType({
    "odom_rot_rel": 0.01, "odom_rot_per_m": 0.0,
    "calibration_std": (0.0, 0.03, math.radians(0.01)), "min_density": 0.5,
    "scan_correlation": 4.0})


@dataclasses.dataclass(frozen=True, kw_only=True)
class LocalizerConfig:
    """Settings of :class:`FusedLocalizer`.

    Attributes:
        occupied_logodds: Log-odds above which a cell of the robot's map is a wall of the
            likelihood field (the mapper's hit adds 0.85, a miss -0.4).
        field_sigma: Standard deviation of the walls' own position in the map, metres.
        range_noise_std: Range noise of a return closer than ``range_noise_from``, m.
        range_noise_rel: Range noise beyond it, as a fraction of the range.
        range_noise_from: Range where the relative noise starts, metres.
        max_distance: Returns farther than this from any wall are outliers, metres.
        scan_correlation: The scan's information is divided by this.
        odom_trans_rel: Standard deviation of a translation increment per metre driven.
        odom_rot_rel: Standard deviation of a rotation increment per radian turned.
        odom_rot_per_m: Standard deviation of the heading per metre driven, radians.
        gate_sigmas: Corrections farther than this many standard deviations of the
            prediction (Mahalanobis) are rejected.
        search_sigmas: When the prediction's position standard deviation times this
            exceeds ``max_distance``, the correlative search seeds the optimisation.
        min_points: Least number of returns to match at all.
        min_inliers: Least fraction of returns within ``max_distance`` of a wall.
        iterations: Most Gauss-Newton iterations.
        field: What the likelihood field is built from: 'returns' (the localiser's own
            density of returns) or 'map' (the occupancy grid given to ``correct``).
        min_density: Weight of returns (1: one at the finest noise) per 5 cm of wall
            (a cell of that side must hold it) before the density has a wall there.
        truncation_sigmas: Returns within this many range-noise standard deviations of
            the range limit are left out.
        density_resolution: Cell side of the density of returns, metres (the map's when
            that is finer).
        calibration_std: Prior standard deviations of the odometry's systematic errors
            the localiser estimates: distance scale (dimensionless), rotation scale
            (dimensionless) and heading change per metre driven (rad/m; with
            ``heading='imu'``, per second: the gyro's bias, rad/s). A zero keeps
            that error out of the state (all zero: no self-calibration). The rotation
            terms' defaults are twice the ``typical`` odometry error's
            (:mod:`mjexplore.sim.odometry`). The distance scale is left out by default:
            the matcher's own lag along the direction of travel (about 0.5 % of the
            distance with the LDS-01's noise) fed into it, and the estimate learnt a 2 %
            scale error on exact odometry.
        heading: Where the odometry's heading comes from: 'wheels' or 'imu' (a gyro,
            :class:`~mjexplore.sim.odometry.Gyro`: its errors grow with time and the
            angle turned, not with the distance driven).
        gyro_noise_density: With ``heading='imu'``, the gyro's rate noise density,
            rad/s/sqrt(Hz): the heading's variance grows by its square per second.
    """

    occupied_logodds: float = 1.0
    field_sigma: float = 0.015
    range_noise_std: float = 0.010
    range_noise_rel: float = 0.035
    range_noise_from: float = 0.5
    max_distance: float = 0.1
    scan_correlation: float = 2.0
    odom_trans_rel: float = 0.03
    odom_rot_rel: float = 0.05
    odom_rot_per_m: float = 0.02
    gate_sigmas: float = 4.0
    search_sigmas: float = 3.0
    min_points: int = 30
    min_inliers: float = 0.5
    iterations: int = 10
    field: str = "returns"
    min_density: float = 1.5
    truncation_sigmas: float = 2.5
    density_resolution: float = 0.02
    calibration_std: tuple[float, float, float] = (0.0, 0.03, 0.015)
    heading: str = "wheels"
    gyro_noise_density: float = math.radians(0.01)

    def __post_init__(self) -> None:
        positive = (self.field_sigma, self.range_noise_std, self.max_distance,
                    self.gate_sigmas, self.search_sigmas)
        non_negative = (self.range_noise_rel, self.range_noise_from, self.odom_trans_rel,
                        self.odom_rot_rel, self.odom_rot_per_m)
        if not (all(v > 0 for v in positive) and all(v >= 0 for v in non_negative) and
                self.scan_correlation >= 1 and self.min_points >= 3 and
                0 <= self.min_inliers <= 1 and self.iterations >= 1 and
                self.field in ("returns", "map") and self.min_density > 0 and
                self.truncation_sigmas >= 0 and self.density_resolution > 0 and
                len(self.calibration_std) == 3 and self.heading in HEADINGS and
                self.gyro_noise_density >= 0 and
                all(v >= 0 and math.isfinite(v) for v in self.calibration_std)):
            raise UserInputError(
                "localizer config needs field_sigma, range_noise_std, max_distance, "
                "gate_sigmas and search_sigmas > 0, the odometry and relative noise terms "
                ">= 0, scan_correlation >= 1, min_points >= 3, min_inliers in [0, 1], "
                "iterations >= 1, field 'returns' or 'map', min_density > 0, "
                "truncation_sigmas >= 0, density_resolution > 0, three finite "
                f"calibration_std >= 0, heading one of {', '.join(HEADINGS)} and "
                "gyro_noise_density >= 0.")

    def wall_density(self, resolution: float) -> float:
        """``min_density`` for a density of cells of side ``resolution`` (metres)."""
        return self.min_density * resolution / 0.05

    @classmethod
    def for_lidar(cls, lidar, heading: str = "wheels", **overrides) -> LocalizerConfig:
        """The settings with the range noise of a lidar model
        (:class:`~mjexplore.sim.lidar.LidarConfig`), for an odometry whose heading comes
        from ``heading`` ('wheels', or 'imu': the gyro's noise model, see
        :data:`GYRO_HEADING`)."""
        sensors = {"range_noise_std": max(lidar.noise_std, 0.005),
                   "range_noise_rel": lidar.noise_rel, "range_noise_from": lidar.noise_rel_from,
                   "heading": heading, **(GYRO_HEADING if heading == "imu" else {})}
        return cls(**{**sensors, **overrides})


# ---------------------------------------------------------------------------- kernels


@numba.njit(cache=True)
def _field_system(dist, points, weights, x, y, yaw, x0, y0, res, gate):
    """The scan's cost and Gauss-Newton system at ``base_link`` pose (x, y, yaw).

    ``dist`` (h, w) holds each cell centre's distance to the nearest wall (m); cell
    (0, 0)'s lower-left corner is at (x0, y0). ``points`` (n, 2) are the returns in
    ``base_link``, ``weights`` their inverse variances (1/m^2). A return's residual is the
    bilinear interpolation of ``dist`` where it falls; beyond ``gate`` metres (or off the
    field) it costs ``gate^2`` and adds nothing to the system.

    Returns:
        (cost = sum of w r^2 / 2, J^T W J (3, 3), J^T W r (3,), returns within the gate).
    """
    h, w = dist.shape
    c, s = math.cos(yaw), math.sin(yaw)
    hess = np.zeros((3, 3))
    grad = np.zeros(3)
    cost = 0.0
    inside = 0
    for k in range(points.shape[0]):
        ax = c * points[k, 0] - s * points[k, 1]
        ay = s * points[k, 0] + c * points[k, 1]
        u = (x + ax - x0) / res - 0.5
        v = (y + ay - y0) / res - 0.5
        j0 = int(math.floor(u))
        i0 = int(math.floor(v))
        wk = weights[k]
        if not (0 <= i0 < h - 1 and 0 <= j0 < w - 1):
            cost += 0.5 * wk * gate * gate
            continue
        fu = u - j0
        fv = v - i0
        d00 = dist[i0, j0]
        d01 = dist[i0, j0 + 1]
        d10 = dist[i0 + 1, j0]
        d11 = dist[i0 + 1, j0 + 1]
        r = ((1 - fv) * ((1 - fu) * d00 + fu * d01) + fv * ((1 - fu) * d10 + fu * d11))
        if r >= gate:
            cost += 0.5 * wk * gate * gate
            continue
        inside += 1
        cost += 0.5 * wk * r * r
        gx = ((1 - fv) * (d01 - d00) + fv * (d11 - d10)) / res
        gy = ((1 - fu) * (d10 - d00) + fu * (d11 - d01)) / res
        accumulate_normal_equations(hess, grad, (gx, gy, gy * ax - gx * ay), wk, r)
    return cost, hess, grad, inside


# ---------------------------------------------------------------------------- field


class LikelihoodField:
    """A smooth "distance to the nearest wall" around a point of a map (a crop of it).

    Built from a density of returns (:meth:`from_density`: the cells holding the most
    returns among their neighbours are the walls, so a wall seen through noisy returns is
    where most of them fell, not the whole band of cells any of them hit, as in an
    occupancy grid) or from wall cells (:meth:`from_walls`: their Euclidean distance
    transform).

    Attributes:
        distance: (h, w) distance of each cell centre to the nearest wall, metres, clipped
            at the ``max_distance`` it was built with.
        origin: (x, y) of the crop's cell (0, 0)'s lower-left corner in ``map``, metres.
        resolution: Cell side, metres.
        walls: Whether there is any wall in the crop.
    """

    def __init__(self, distance: np.ndarray, origin: tuple[float, float], resolution: float,
                 walls: bool) -> None:
        if distance.shape[0] < 2 or distance.shape[1] < 2:
            distance, walls = np.zeros((2, 2)), False
        self.distance = distance.astype(np.float64)
        self.origin = origin
        self.resolution = resolution
        self.walls = walls

    @staticmethod
    def _crop(shape: tuple[int, int], resolution: float, origin: tuple[float, float],
              centre: np.ndarray, reach: float) -> tuple[slice, slice, tuple[float, float]]:
        rows, cols = shape
        c0, r0 = np.floor((np.asarray(centre[:2]) - np.asarray(origin[:2])) / resolution
                          ).astype(int)
        k = int(math.ceil(reach / resolution))
        r_lo, c_lo = min(max(r0 - k, 0), rows), min(max(c0 - k, 0), cols)
        r_hi, c_hi = min(max(r0 + k + 1, 0), rows), min(max(c0 + k + 1, 0), cols)
        return (slice(r_lo, r_hi), slice(c_lo, c_hi),
                (origin[0] + c_lo * resolution, origin[1] + r_lo * resolution))

    @classmethod
    def from_walls(cls, walls: np.ndarray, resolution: float, origin: tuple[float, float],
                   centre: np.ndarray, reach: float, max_distance: float) -> LikelihoodField:
        """The field of the wall cells (bool (rows, cols)) within ``reach`` (m) of
        ``centre`` (x, y); ``origin`` is cell (0, 0)'s lower-left corner (m)."""
        rs, cs, crop_origin = cls._crop(walls.shape, resolution, origin, centre, reach)
        crop = walls[rs, cs]
        if not crop.any():
            return cls(np.full(crop.shape, max_distance), crop_origin, resolution, False)
        dist = cv2.distanceTransform((~crop).astype(np.uint8), cv2.DIST_L2,
                                     cv2.DIST_MASK_PRECISE) * resolution
        return cls(np.minimum(dist, max_distance), crop_origin, resolution, True)

    @classmethod
    def from_density(cls, density: np.ndarray, resolution: float, origin: tuple[float, float],
                     centre: np.ndarray, reach: float, max_distance: float, blur: float,
                     min_density: float) -> LikelihoodField:
        """The field of a density of returns ((rows, cols) weights per cell).

        The density blurred by a Gaussian of ``blur`` metres, divided by its maximum
        within ``2 blur`` (at least the next cells: so a wall's cells holding the most
        returns are 1 however often the wall was seen; a crop whose densest cell is below
        ``min_density`` has no wall yet), is taken as the likelihood
        ``exp(-d^2 / (2 blur^2))`` of a return at distance ``d`` from a wall; ``d``,
        clipped at ``max_distance``, is the field. With ``blur`` below a cell, a cell two
        cells from any return is at ``max_distance``: returns there are outliers.
        """
        rs, cs, crop_origin = cls._crop(density.shape, resolution, origin, centre, reach)
        crop = density[rs, cs]
        if crop.size == 0 or not crop.max() >= min_density:
            return cls(np.full(crop.shape, max_distance), crop_origin, resolution, False)
        sigma = blur / resolution
        smooth = cv2.GaussianBlur(crop, (0, 0), sigma)
        k = 2 * int(math.ceil(2 * sigma)) + 1
        peak = cv2.dilate(smooth, np.ones((k, k), np.uint8))
        norm = smooth / np.maximum(peak, min_density / (math.sqrt(2 * math.pi) * sigma))
        with np.errstate(divide="ignore"):  # log(0): no return nearby, clipped below.
            dist = blur * np.sqrt(-2.0 * np.log(np.minimum(norm.astype(np.float64), 1.0)))
        return cls(np.minimum(dist, max_distance), crop_origin, resolution, True)


def _walls_at(field: LikelihoodField, within: float, resolution: float) -> GridMap:
    """The field's walls (cells within ``within`` metres of one) as a trinary map whose
    cells are blocks of the field's, about ``resolution`` metres wide (a coarser lattice
    keeps Olson's search cheap)."""
    near = field.distance < within
    k = max(int(round(resolution / field.resolution)), 1)
    rows, cols = -(-near.shape[0] // k) * k, -(-near.shape[1] // k) * k
    padded = np.zeros((rows, cols), bool)
    padded[:near.shape[0], :near.shape[1]] = near
    blocks = padded.reshape(rows // k, k, cols // k, k).any(axis=(1, 3))
    return GridMap(np.where(blocks, 100, 0).astype(np.int8), field.resolution * k,
                   (*field.origin, 0.0))


def wall_cells(grid, occupied_logodds: float) -> tuple[np.ndarray, float, tuple[float, float]]:
    """The wall cells of a map, its resolution and origin (x, y).

    Args:
        grid: An :class:`~mjexplore.mapping.occupancy.OccupancyMapper` (its log-odds above
            ``occupied_logodds`` are walls) or a :class:`GridMap` (its occupied cells).
        occupied_logodds: See :class:`LocalizerConfig`.
    """
    if isinstance(grid, GridMap):
        return is_occupied(grid.data), grid.resolution, (grid.origin[0], grid.origin[1])
    return grid.logodds > occupied_logodds, grid.config.resolution, tuple(grid.origin[:2])


def neighbour_ranges(ranges: np.ndarray, half: int = 2) -> np.ndarray:
    """Each beam's range as its neighbours read it: the median of the finite ranges of the
    ``half`` beams on either side (not its own; the beams wrap around), NaN where none is
    finite. Unlike the beam's own reading, it does not depend on the beam's noise.

    Args:
        ranges: (n,) ranges of a scan in beam order, metres (non-finite: no return).
    """
    r = np.asarray(ranges, dtype=np.float64)
    r = np.where(np.isfinite(r), r, np.nan)
    around = np.stack([np.roll(r, k) for k in range(-half, half + 1) if k != 0])
    out = np.full(len(r), np.nan)
    some = ~np.isnan(around).all(axis=0)
    out[some] = np.nanmedian(around[:, some], axis=0)
    return out


def deposit(density: np.ndarray, resolution: float, origin: tuple[float, float],
            pose: np.ndarray, points: np.ndarray, weights: np.ndarray) -> None:
    """Adds returns to a density of returns (in place), each shared bilinearly among the
    four cells whose centres surround it, so that the density's peak (and the likelihood
    field interpolated between cell centres) keeps the returns' position below a cell. A
    return dropped whole into the cell it falls in would sit at the cell's centre: a wall
    face on a cell boundary (every axis-aligned wall of a generated scene) moved by half a
    cell, and the estimate with it (2.5 cm in x and y at 5 cm cells).

    Args:
        density: (rows, cols) float32 weights per cell; cell (0, 0)'s lower-left corner is
            at ``origin`` (x, y), metres.
        resolution: Cell side, metres.
        origin: See ``density``.
        pose: (x, y, yaw) of the frame of ``points`` in the density's frame.
        points: (n, 2) returns, metres.
        weights: (n,) weight of each.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    u = (pose[0] + c * points[:, 0] - s * points[:, 1] - origin[0]) / resolution - 0.5
    v = (pose[1] + s * points[:, 0] + c * points[:, 1] - origin[1]) / resolution - 0.5
    c0, r0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - c0, v - r0
    w = np.asarray(weights, np.float64)
    rows, cols = density.shape
    for dr, dc, share in ((0, 0, (1 - fu) * (1 - fv)), (0, 1, fu * (1 - fv)),
                          (1, 0, (1 - fu) * fv), (1, 1, fu * fv)):
        r, col = r0 + dr, c0 + dc
        ok = (r >= 0) & (r < rows) & (col >= 0) & (col < cols)
        np.add.at(density, (r[ok], col[ok]), (w * share)[ok].astype(np.float32))


def optimise_pose(field: LikelihoodField, points: np.ndarray, weights: np.ndarray,
                  start: np.ndarray, prior: np.ndarray, prior_info: np.ndarray,
                  gate: float, iterations: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Gauss-Newton on a scan's cost in a likelihood field plus a Gaussian prior's, halving
    steps that do not lower it.

    Args:
        field: The field.
        points: (n, 2) returns in the frame whose pose is sought, metres.
        weights: (n,) their inverse variances, 1/m^2.
        start: Pose to start from (x, y, yaw in the field's frame).
        prior: Mean of the prior.
        prior_info: Its 3 x 3 information (inverse covariance).
        gate: Returns farther than this from any wall are outliers, metres.
        iterations: Most iterations.

    Returns:
        (pose, the Hessian there (the scan's plus the prior's information), fraction of
        returns within ``gate`` of a wall).
    """
    def system(p: np.ndarray):
        cost, hess, grad, inside = _field_system(
            field.distance, points, weights, p[0], p[1], p[2], field.origin[0],
            field.origin[1], field.resolution, gate)
        d = p - prior
        d[2] = wrap_angle(d[2])
        return (cost + 0.5 * d @ prior_info @ d, hess + prior_info, grad + prior_info @ d,
                inside)

    pose = np.array(start, dtype=float)
    cost, hess, grad, inside = system(pose)
    for _ in range(iterations):
        step = -np.linalg.solve(hess, grad)
        for _ in range(5):
            trial = pose + step
            new = system(trial)
            if new[0] < cost:
                break
            step = step / 2
        else:
            break
        pose = trial
        cost, hess, grad, inside = new
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    pose[2] = wrap_angle(pose[2])
    return pose, hess, inside / max(len(points), 1)


# ---------------------------------------------------------------------------- localiser


@dataclasses.dataclass(frozen=True)
class FusionResult:
    """The outcome of one :meth:`FusedLocalizer.correct`.

    Attributes:
        prior: Predicted (x, y, yaw) of ``base_link`` in ``map``.
        pose: The estimate after the update (the prior when rejected).
        covariance: Its 3 x 3 covariance.
        points: Returns used.
        inliers: Fraction of them within ``max_distance`` of a wall at ``pose``.
        mahalanobis: The correction's distance from the prior in its standard deviations.
        searched: True when the correlative search seeded the optimisation.
        accepted: True when the update was taken.
    """

    prior: np.ndarray
    pose: np.ndarray
    covariance: np.ndarray
    points: int
    inliers: float
    mahalanobis: float
    searched: bool
    accepted: bool


class FusedLocalizer(LocalizerBase[FusionResult]):
    """The pose of ``base_link`` in ``map`` and its covariance: odometry fused with scans
    matched against the robot's own map (see the module docstring). ``pose``,
    ``sensor_pose``, ``advance`` and ``map_to_odom`` are
    :class:`~mjexplore.mapping.scan_matching.LocalizerBase`'s.

    Args:
        pose: Initial (x, y, yaw) of ``base_link`` in ``map``.
        odom_pose: The odometry's reading (``base_link`` in ``odom``) at ``pose``, from
            which :meth:`advance` counts; None: from its first call.
        config: Settings.
        geometry: The robot (where ``base_scan`` sits on ``base_link``).
        covariance: Initial covariance (default: 1 cm and 0.5 degree standard deviations).

    Attributes:
        last_match: The latest :meth:`correct`'s result (None before any).
        matches: Number of accepted updates.
        rejections: Number of rejected ones.
    """

    def __init__(self, pose: tuple[float, float, float] | np.ndarray,
                 odom_pose: tuple[float, float, float] | np.ndarray | None = None,
                 config: LocalizerConfig | None = None,
                 geometry: RobotGeometry = TURTLEBOT3_WAFFLE,
                 covariance: np.ndarray | None = None) -> None:
        self.config = config or LocalizerConfig()
        self.geometry = geometry
        self.reset(pose, odom_pose, covariance)

    def reset(self, pose: tuple[float, float, float] | np.ndarray,
              odom_pose: tuple[float, float, float] | np.ndarray | None = None,
              covariance: np.ndarray | None = None, keep_map: bool = False) -> None:
        """Restarts at ``pose`` (``map``) with ``covariance``; ``odom_pose`` is the
        odometry's reading there. ``keep_map`` keeps the returns gathered so far and the
        odometry's calibration (a re-localisation in the same map, as AMCL's initial
        pose)."""
        super().reset(pose, odom_pose)
        pose_cov = (np.diag([0.01 ** 2, 0.01 ** 2, math.radians(0.5) ** 2])
                    if covariance is None else np.array(covariance, dtype=float))
        if keep_map:
            calibration_cov = self._cov[3:, 3:].copy()
        else:
            self._calibration = np.array([1.0, 1.0, 0.0])
            calibration_cov = np.diag(np.square(self.config.calibration_std))
        self._cov: np.ndarray = np.zeros((6, 6))
        self._cov[:3, :3], self._cov[3:, 3:] = pose_cov, calibration_cov
        if not keep_map:
            self._density: np.ndarray | None = None
            self._density_geometry: tuple[float, tuple[float, float]] | None = None

    @property
    def covariance(self) -> np.ndarray:
        """3 x 3 covariance of the pose estimate (m^2, m rad, rad^2)."""
        return self._cov[:3, :3].copy()

    @property
    def calibration(self) -> np.ndarray:
        """The odometry's estimated systematic errors: (distance scale, rotation scale,
        heading change per metre driven in rad/m, or with a gyro heading per second: minus
        its bias in rad/s); (1, 1, 0) is an exact odometry."""
        return self._calibration.copy()

    @property
    def calibration_std(self) -> np.ndarray:
        """Standard deviations of :attr:`calibration`."""
        return np.sqrt(np.diag(self._cov)[3:])

    def predict(self, odom_delta: tuple[float, float, float] | np.ndarray,
                dt: float = 0.0) -> None:
        """Moves the estimate by an odometry increment (x, y, yaw) given in the previous
        ``base_link`` frame and taken over ``dt`` seconds, corrected by the estimated
        calibration, and grows the covariance by the increment's and the calibration's."""
        cfg = self.config
        dx, dy, dth = (float(v) for v in odom_delta)
        dist = math.hypot(dx, dy)
        gyro = cfg.heading == "imu"
        # The third calibration term's unit: seconds for a gyro's bias; for the wheels'
        # radius ratio metres driven, signed (reversing turns the heading error back).
        unit = dt if gyro else math.copysign(dist, dx)
        scale, rot_scale, drift = self._calibration
        ux, uy, uth = scale * dx, scale * dy, rot_scale * dth + drift * unit
        c, s = math.cos(self._pose[2]), math.sin(self._pose[2])
        jacobian = np.eye(6)
        jacobian[:2, 2] = (-s * ux - c * uy, c * ux - s * uy)
        jd = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        jacobian[:3, 3:] = jd @ np.array([[dx, 0.0, 0.0], [dy, 0.0, 0.0], [0.0, dth, unit]])
        trans = (cfg.odom_trans_rel * dist) ** 2 + 1e-8
        q = np.diag([trans, trans, (cfg.odom_rot_rel * dth) ** 2 +
                     (cfg.odom_rot_per_m * dist) ** 2 +
                     (cfg.gyro_noise_density ** 2 * dt if gyro else 0.0) + 1e-8])
        self._cov = jacobian @ self._cov @ jacobian.T
        self._cov[:3, :3] += jd @ q @ jd.T
        self._pose = compose_pose(self._pose, (ux, uy, uth))

    def correct(self, scan: LaserScan, grid) -> FusionResult:
        """Updates the estimate with a scan taken at the estimate's time.

        Args:
            scan: The scan, de-skewed when taken while moving
                (:func:`~mjexplore.mapping.scan_matching.deskew_scan`); its ``pose`` (the
                ground truth) is not used.
            grid: The robot's map: an :class:`~mjexplore.mapping.occupancy.OccupancyMapper`
                (log-odds, preferred) or a :class:`GridMap`.

        Returns:
            The update's outcome.
        """
        cfg = self.config
        prior, prior_cov = self._pose.copy(), self.covariance
        sensor_points = scan_points(scan)
        # Each return is kept and weighted by the range its neighbours read, never by its
        # own: trusting a return more, or keeping it, because it reads short biases the
        # walls towards the robot: walls ahead come nearer and the estimate lags behind
        # (with the LDS-01's 3.5 % noise, 3.7 mm per metre down a corridor; 1.7 this way).
        ranges = neighbour_ranges(scan.ranges)[np.isfinite(scan.ranges)]
        ranges = np.where(np.isnan(ranges), np.hypot(*sensor_points.T), ranges)
        # Returns near the range limit are biased short (those the noise took past the
        # limit are missing): they are left out of the matching and of the density.
        far = scan.range_max * (1.0 - cfg.truncation_sigmas * cfg.range_noise_rel)
        sensor_points, ranges = sensor_points[ranges < far], ranges[ranges < far]
        ox, oy, _ = self.geometry.scan_offset
        points = sensor_points + (ox, oy)  # base_scan is not turned on base_link.
        noise = range_noise_std(ranges, cfg.range_noise_std, cfg.range_noise_rel,
                                cfg.range_noise_from)
        n = len(points)
        weights = 1.0 / (cfg.field_sigma ** 2 + noise ** 2)
        if isinstance(grid, GridMap):
            shape, res, origin = grid.shape, grid.resolution, (grid.origin[0], grid.origin[1])
        else:
            shape, res, origin = grid.logodds.shape, grid.config.resolution, tuple(grid.origin)
        map_res = res
        if cfg.field == "returns":
            # The density has its own, finer cells: a wall's position below a cell of it
            # is lost (see :func:`deposit`), so they are kept well below the map's.
            res = min(map_res, cfg.density_resolution)
            dshape = tuple(int(math.ceil(k * map_res / res - 1e-9)) for k in shape)
            if self._density is None or self._density_geometry != (res, origin) or \
                    self._density.shape != dshape:
                self._density = np.zeros(dshape, np.float32)
                self._density_geometry = (res, origin)
        reach = (float(ranges.max()) if n else 0.0) + cfg.max_distance + 4 * res
        searched = False
        start = prior
        position_sd = math.sqrt(max(np.linalg.eigvalsh(prior_cov[:2, :2])[-1], 0.0))
        # The prediction too uncertain for the field's basin: Olson's search first, within
        # this window (metres).
        search = cfg.search_sigmas * position_sd > cfg.max_distance and n >= cfg.min_points
        window = min(cfg.search_sigmas * position_sd, 1.0) if search else 0.0
        reach += window
        if cfg.field == "returns":
            assert self._density is not None  # Made above for this field.
            field = LikelihoodField.from_density(self._density, res, origin, prior[:2], reach,
                                                 cfg.max_distance, cfg.field_sigma,
                                                 cfg.wall_density(res))
        else:
            walls, res, origin = wall_cells(grid, cfg.occupied_logodds)
            field = LikelihoodField.from_walls(walls, res, origin, prior[:2], reach,
                                               cfg.max_distance)
        if n < cfg.min_points or not field.walls:
            return self._finish(self._reject(prior, prior_cov, n, 0.0, math.inf, False),
                                points, noise)
        if search:
            angular = min(cfg.search_sigmas * math.sqrt(prior_cov[2, 2]), math.radians(20))
            trinary = _walls_at(field, 0.5 * map_res, map_res)
            match = match_scan(sensor_points, trinary, self.sensor_pose, ScanMatcherConfig(
                linear_window=window, angular_window=max(angular, math.radians(2)),
                sigma=max(2 * cfg.field_sigma, trinary.resolution), refine_iterations=0,
                min_score=0.2))
            if match.accepted:
                start, searched = base_pose_of(match.pose, self.geometry), True
        pose, hessian, inliers = optimise_pose(field, points, weights / cfg.scan_correlation,
                                               start, prior, np.linalg.inv(prior_cov),
                                               cfg.max_distance, cfg.iterations)
        delta = pose - prior
        delta[2] = wrap_angle(delta[2])
        mahalanobis = float(math.sqrt(max(delta @ np.linalg.solve(prior_cov, delta), 0.0)))
        if inliers < cfg.min_inliers or mahalanobis > cfg.gate_sigmas:
            return self._finish(self._reject(prior, prior_cov, n, inliers, mahalanobis,
                                             searched), points, noise)
        covariance = np.linalg.inv(hessian)
        self._update_calibration(delta, 0.5 * (covariance + covariance.T))
        self._pose = pose
        self.matches += 1
        self.last_match = FusionResult(prior, pose.copy(), self.covariance, n, inliers,
                                       mahalanobis, searched, True)
        return self._finish(self.last_match, points, noise)

    def _update_calibration(self, delta: np.ndarray, pose_cov: np.ndarray) -> None:
        """Conditions the calibration on the matched pose: the scan measured the pose only,
        so the calibration moves by its regression on the pose's correction ``delta``, and
        the joint covariance follows (exact for a Gaussian; ``pose_cov`` is the pose's
        posterior)."""
        prior_pose_cov = self._cov[:3, :3]
        gain = np.linalg.solve(prior_pose_cov, self._cov[:3, 3:]).T  # (3 calib, 3 pose)
        cross = gain @ pose_cov
        calibration_cov = self._cov[3:, 3:] - gain @ self._cov[:3, 3:] + cross @ gain.T
        self._calibration = self._calibration + gain @ delta
        self._cov[:3, :3], self._cov[3:, :3] = pose_cov, cross
        self._cov[:3, 3:], self._cov[3:, 3:] = cross.T, 0.5 * (calibration_cov +
                                                               calibration_cov.T)

    def _finish(self, result: FusionResult, points: np.ndarray, noise: np.ndarray
                ) -> FusionResult:
        """Adds the scan's returns, at the estimate, to the density the field comes from
        (each weighted by its precision relative to the finest: far returns count less)."""
        if self._density is not None:
            assert self._density_geometry is not None  # Set with the density.
            res, origin = self._density_geometry
            deposit(self._density, res, origin, self._pose, points,
                    self.config.range_noise_std / noise)
        return result

    def _reject(self, prior, prior_cov, n, inliers, mahalanobis, searched) -> FusionResult:
        self.rejections += 1
        self.last_match = FusionResult(prior, prior.copy(), prior_cov, n, inliers,
                                       mahalanobis, searched, False)
        return self.last_match
