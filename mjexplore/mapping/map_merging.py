"""Map-to-map merging: where one robot's map lies in another's, by correlative matching.

Two robots that do not know where they started relative to each other each map in a frame
of their own (its origin is the robot's start pose). Once their maps overlap, the pose of one
map's frame in the other's is found by matching the *wall points* of map ``b`` (the centres
of its occupied cells next to a free or unknown one, in ``b``'s frame) against map ``a``:

1. **Rotation candidates** (Carpin, "Fast and accurate map merging for multirobot systems",
   Autonomous Robots 2008): the Hough spectra of the two maps' wall points (per line
   direction, the sum of squares of the Hough counts) are shifted copies of each other by
   the rotation between the maps; the peaks of their circular cross-correlation, each with
   its half-turn twin, are the candidate rotations (``rotations`` of them).
2. **Global translation search** at a coarse resolution (``coarse_resolution``, maps pooled:
   a coarse cell is occupied if any of its cells is): for each candidate rotation and
   ``angle_spread`` steps of ``angle_step`` around it, every translation over all of ``a``
   is scored at once by an FFT cross-correlation of ``b``'s rasterised wall points with
   ``a``'s score table (a Gaussian of the distance to ``a``'s walls, minus one on ``a``'s
   free space clear of its walls, so that walls across free space count against).
3. **Refinement** of the ``refined`` best-scoring coarse poses at the maps' resolution with
   the project's correlative matcher (:func:`~mjexplore.mapping.scan_matching.match_scan`:
   a small window, then its Gauss-Newton refinement), ``b``'s wall points taken as the
   returns of a scan from ``b``'s origin.
4. **Verification** (a match is only a candidate until it passes): at the refined pose,
   ``b``'s wall points that fall on cells ``a`` knows must lie on ``a``'s walls (within
   ``inlier_distance``), and the other way round; ``b``'s free space, kept
   ``conflict_margin`` away from its walls and unknown cells, must not fall on ``a``'s
   walls and must cover ``min_free_overlap`` of ``a``'s free space; the walls both agree on
   must add up to ``min_wall_overlap`` metres; and the refinement must not be degenerate
   (a featureless corridor). A false alignment of two similar rooms puts walls across free
   space and fails; too little overlap is no answer yet.

All poses are (x, y, yaw) in metres and radians, REP-103; a map's frame is the one its
:class:`~mjexplore.maps.GridMap` origin is given in.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import scipy.fft

from mjexplore.errors import UserInputError
from mjexplore.mapping.scan_matching import ScanMatcherConfig, match_scan
from mjexplore.maps import GridMap, is_free, is_known, is_occupied


@dataclasses.dataclass(frozen=True, kw_only=True)
class MapMergeConfig:
    """Settings of :func:`merge_maps`.

    Attributes:
        coarse_resolution: Cell side of the global search's pooled maps, metres.
        refine_window: Half-width of the refinement's translation window, metres.
        refine_angle: Half-width of the refinement's rotation window, radians.
        inlier_distance: A wall point within this distance of the other map's wall agrees
            with it, metres.
        min_inliers: Least fraction of the wall points (each map's, on the cells the other
            knows) that agree.
        max_conflict: Most fraction of ``b``'s free cells (those ``conflict_margin`` from
            its walls and unknown cells, on cells ``a`` knows) that fall on ``a``'s walls.
        conflict_margin: See ``max_conflict``, metres.
        min_wall_overlap: Least length of wall both maps agree on, metres (agreeing wall
            points of ``b`` times the cell side).
        min_free_overlap: Least area of ``b``'s free cells (those ``conflict_margin`` from
            its walls and unknown cells) that fall on ``a``'s free cells, square metres.
        max_points: At most this many wall points are matched (evenly thinned), per stage.
        rotations: Rotation candidates (peaks of the Hough spectra's correlation) tried,
            each with its half-turn twin.
        angle_step: Step of the rotations searched around each candidate, radians.
        angle_spread: Steps searched on either side of each candidate.
        refined: The coarse search's best rotations (one pose each) refined and verified.
    """

    coarse_resolution: float = 0.2
    refine_window: float = 0.4
    refine_angle: float = math.radians(3.0)
    inlier_distance: float = 0.1
    min_inliers: float = 0.8
    max_conflict: float = 0.01
    conflict_margin: float = 0.15
    min_wall_overlap: float = 15.0
    min_free_overlap: float = 10.0
    max_points: int = 4000
    rotations: int = 4
    angle_step: float = math.radians(0.5)
    angle_spread: int = 2
    refined: int = 3

    def __post_init__(self) -> None:
        if not (self.coarse_resolution > 0 and
                self.refine_window >= 0 and 0 <= self.refine_angle < math.pi and
                self.inlier_distance > 0 and 0 <= self.min_inliers <= 1 and
                0 <= self.max_conflict <= 1 and self.conflict_margin >= 0 and
                self.min_wall_overlap >= 0 and self.min_free_overlap >= 0 and
                self.max_points >= 3 and self.rotations >= 1 and self.refined >= 1 and
                self.angle_step > 0 and self.angle_spread >= 0):
            raise UserInputError(
                "map merge config needs coarse_resolution > 0, "
                "refine_window >= 0, refine_angle in [0, pi), inlier_distance > 0, "
                "min_inliers and max_conflict in [0, 1], conflict_margin >= 0, "
                "min_wall_overlap >= 0, min_free_overlap >= 0, max_points >= 3, "
                "rotations >= 1, refined >= 1, angle_step > 0 and angle_spread >= 0.")


@dataclasses.dataclass(frozen=True)
class MergeResult:
    """The outcome of one map-to-map match.

    Attributes:
        pose: (x, y, yaw) of map ``b``'s frame in map ``a``'s frame (metres, radians).
        score: The refinement's correlative score (mean lookup-table value, 0..1) over all
            of ``b``'s wall points, those on ``a``'s unknown cells included.
        inliers: The lesser of the two maps' fractions of wall points that agree.
        conflict: Fraction of ``b``'s free cells that fall on ``a``'s walls.
        wall_overlap: Length of wall both maps agree on, metres.
        free_overlap: Area of ``b``'s free space on ``a``'s, square metres.
        degenerate: True when the refinement found a direction the walls do not fix (a
            corridor without features along it).
        accepted: True when the match passed the verification.
    """

    pose: np.ndarray
    score: float
    inliers: float
    conflict: float
    wall_overlap: float
    free_overlap: float
    degenerate: bool
    accepted: bool


def wall_cells(grid: GridMap) -> np.ndarray:
    """(n, 2) (row, col) of the occupied cells with a free or unknown 4-neighbour (a thick
    wall's inside is not where returns fall)."""
    occupied = is_occupied(grid.data).astype(np.uint8)
    inner = cv2.erode(occupied, np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=1)
    return np.argwhere((occupied == 1) & (inner == 0))


def pool_grid(grid: GridMap, resolution: float) -> GridMap:
    """``grid`` at a coarser ``resolution`` (a whole multiple of its own): a coarse cell is
    occupied (100) if any of its cells is, else free (0) if any is, else unknown."""
    f = max(int(round(resolution / grid.resolution)), 1)
    rows, cols = grid.shape
    pr, pc = -rows % f, -cols % f
    data = np.pad(grid.data, ((0, pr), (0, pc)), constant_values=-1)
    blocks = data.reshape((rows + pr) // f, f, (cols + pc) // f, f)
    occupied = is_occupied(blocks).any(axis=(1, 3))
    free = is_free(blocks).any(axis=(1, 3))
    out = np.where(occupied, 100, np.where(free, 0, -1)).astype(np.int8)
    return GridMap(out, grid.resolution * f, grid.origin)


def _thin(points: np.ndarray, most: int) -> np.ndarray:
    if len(points) <= most:
        return points
    return points[np.linspace(0, len(points) - 1, most).astype(np.int64)]


def _transform(pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([pose[0] + c * xy[:, 0] - s * xy[:, 1],
                            pose[1] + s * xy[:, 0] + c * xy[:, 1]])


def _inverse(pose: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([-c * pose[0] - s * pose[1], s * pose[0] - c * pose[1], -pose[2]])


class _Facts:
    """What the verification reads of one map: its wall points (its frame, metres), each
    cell's distance to its walls (cells), and its free cells clear of its walls and unknown
    by ``margin`` metres (points, its frame)."""

    def __init__(self, grid: GridMap, margin: float) -> None:
        self.grid = grid
        self.walls = grid.cell_to_world(wall_cells(grid))
        occupied = is_occupied(grid.data)
        self.distance = (cv2.distanceTransform((~occupied).astype(np.uint8), cv2.DIST_L2,
                                               cv2.DIST_MASK_5) if occupied.any() else
                         np.full(grid.shape, np.inf, np.float32))
        k = int(math.ceil(margin / grid.resolution))
        solid = (~is_free(grid.data)).astype(np.uint8)
        clear = cv2.dilate(solid, np.ones((2 * k + 1,) * 2, np.uint8),
                           borderType=cv2.BORDER_CONSTANT, borderValue=1) == 0
        self.clear = grid.cell_to_world(np.argwhere(clear))

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The map's values and wall distances (cells) at ``points`` that fall on it."""
        rc = self.grid.world_to_cell(points)
        rc = rc[self.grid.in_bounds(rc)]
        return self.grid.data[rc[:, 0], rc[:, 1]], self.distance[rc[:, 0], rc[:, 1]]


def _verify(fa: _Facts, fb: _Facts, pose: np.ndarray, cfg: MapMergeConfig
            ) -> tuple[float, float, float, float]:
    fractions = []
    for into, points, where in ((fa, fb.walls, pose), (fb, fa.walls, _inverse(pose))):
        values, distance = into.lookup(_transform(where, points))
        seen = is_known(values)
        near = int((distance[seen] * into.grid.resolution <= cfg.inlier_distance).sum())
        fractions.append((near, int(seen.sum())))
    inliers = min(near / max(seen, 1) for near, seen in fractions)
    values, _ = fa.lookup(_transform(pose, fb.clear))
    seen = is_known(values)
    conflict = float(is_occupied(values[seen]).sum() / max(int(seen.sum()), 1))
    free = float(is_free(values).sum()) * fb.grid.resolution ** 2
    return float(inliers), conflict, fractions[0][0] * fb.grid.resolution, free


def verify_merge(a: GridMap, b: GridMap, pose: np.ndarray,
                 config: MapMergeConfig | None = None) -> tuple[float, float, float, float]:
    """How well map ``b`` placed at ``pose`` in ``a``'s frame agrees with ``a``.

    Returns:
        (inliers: the lesser of the maps' fractions of wall points on the other's known
        cells that lie on its walls; conflict: the fraction of ``b``'s free cells, kept
        ``conflict_margin`` from its walls and unknown cells, on ``a``'s known cells that
        fall on ``a``'s walls; wall overlap: metres of ``b``'s wall that agree; free
        overlap: square metres of those free cells of ``b`` on ``a``'s free cells).
    """
    cfg = config or MapMergeConfig()
    return _verify(_Facts(a, cfg.conflict_margin), _Facts(b, cfg.conflict_margin),
                   np.asarray(pose, float), cfg)


def hough_spectrum(points: np.ndarray, resolution: float, bins: int = 180) -> np.ndarray:
    """Carpin's Hough spectrum of (n, 2) points: for each of ``bins`` line directions over
    half a turn, the sum of squares of the Hough transform's counts along it (distances
    quantised at ``resolution``). A rotation of the points shifts it circularly."""
    theta = np.arange(bins) * (math.pi / bins)
    rho = np.floor((points[:, :1] * np.cos(theta) + points[:, 1:] * np.sin(theta))
                   / resolution).astype(np.int64)
    rho -= rho.min()
    width = int(rho.max()) + 1
    counts = np.bincount((rho + width * np.arange(bins)).ravel(), minlength=width * bins)
    return (counts.reshape(bins, width).astype(float) ** 2).sum(axis=1)


def rotation_candidates(points_a: np.ndarray, points_b: np.ndarray, resolution: float,
                        count: int, bins: int = 180) -> np.ndarray:
    """The ``count`` likeliest rotations of ``b``'s points onto ``a``'s (radians), each with
    its half-turn twin: the peaks of the circular cross-correlation of their Hough spectra
    (at least 5 degrees apart)."""
    sa = hough_spectrum(points_a, resolution, bins)
    sb = hough_spectrum(points_b, resolution, bins)
    sa, sb = sa - sa.mean(), sb - sb.mean()
    corr = np.real(np.fft.ifft(np.fft.fft(sa) * np.conj(np.fft.fft(sb))))
    order = np.argsort(-corr)
    gap = max(int(round(bins * 5 / 180)), 1)
    peaks: list[int] = []
    for k in order:
        if all(min(abs(k - p), bins - abs(k - p)) >= gap for p in peaks):
            peaks.append(int(k))
        if len(peaks) == count:
            break
    angles = np.array(peaks) * (math.pi / bins)
    return np.concatenate([angles, angles + math.pi])


def _translation_search(table: np.ndarray, points: np.ndarray, yaws: np.ndarray,
                        grid: GridMap) -> tuple[float, np.ndarray]:
    """Best score and (x, y, yaw) of ``points`` (their frame's origin) over every cell
    translation and the given rotations: FFT cross-correlation of the rasterised points
    with ``table`` (a map's score per cell, ``grid``'s cells)."""
    res = grid.resolution
    reach = float(np.hypot(points[:, 0], points[:, 1]).max()) + res
    side = int(math.ceil(2 * reach / res)) + 1
    shape = (scipy.fft.next_fast_len(table.shape[0] + side, real=True),
             scipy.fft.next_fast_len(table.shape[1] + side, real=True))
    spectrum = np.conj(scipy.fft.rfft2(table.astype(np.float32), shape))
    best, best_pose = -np.inf, np.zeros(3)
    for yaw in yaws:
        c, s = math.cos(yaw), math.sin(yaw)
        u = np.floor((c * points[:, 0] - s * points[:, 1] + reach) / res).astype(np.int64)
        v = np.floor((s * points[:, 0] + c * points[:, 1] + reach) / res).astype(np.int64)
        raster = np.bincount(v * side + u, minlength=side * side).reshape(side, side)
        corr = scipy.fft.irfft2(scipy.fft.rfft2(raster.astype(np.float32), shape) * spectrum,
                                shape)
        # corr[k] = sum_w raster[w] table[w - k]: raster cell (0, 0) on table cell -k.
        k = np.unravel_index(int(np.argmax(corr)), shape)
        if corr[k] > best:
            di = -k[0] if k[0] < side else shape[0] - k[0]
            dj = -k[1] if k[1] < side else shape[1] - k[1]
            best = float(corr[k])
            # Raster cell (0, 0) at table cell (di, dj): the origin sits reach from it.
            best_pose = np.array([grid.origin[0] + dj * res + reach,
                                  grid.origin[1] + di * res + reach, yaw])
    return best / len(points), best_pose


def merge_maps(a: GridMap, b: GridMap, config: MapMergeConfig | None = None) -> MergeResult:
    """Finds the pose of map ``b``'s frame in map ``a``'s frame (see the module docstring).

    Args:
        a: The map to match against (e.g. the team's).
        b: The map to place (e.g. a robot's own, in its start frame).
        config: Search and acceptance settings.

    Returns:
        The best verified match (or the best one, not accepted, when none passes).
    """
    cfg = config or MapMergeConfig()
    walls = b.cell_to_world(wall_cells(b))
    none = MergeResult(np.zeros(3), 0.0, 0.0, 1.0, 0.0, 0.0, True, False)
    if len(walls) < 3 or not is_occupied(a.data).any():
        return none
    coarse_a, coarse_b = pool_grid(a, cfg.coarse_resolution), pool_grid(b, cfg.coarse_resolution)
    points_b = _thin(coarse_b.cell_to_world(wall_cells(coarse_b)), cfg.max_points)
    points_a = coarse_a.cell_to_world(wall_cells(coarse_a))
    if len(points_b) < 3 or len(points_a) < 3:
        return none
    res = coarse_a.resolution
    # The score per coarse cell of a: near a wall (a Gaussian of the distance, sigma one
    # coarse cell), minus one on free space clear of a's walls.
    dist = _Facts(coarse_a, 0.0).distance.astype(float)
    table = np.exp(-0.5 * dist ** 2) - (is_free(coarse_a.data) & (dist > 1.5))
    offsets = cfg.angle_step * np.arange(-cfg.angle_spread, cfg.angle_spread + 1)
    coarse = [_translation_search(table, points_b, theta + offsets, coarse_a)
              for theta in rotation_candidates(points_a, points_b, res, cfg.rotations)]
    coarse.sort(key=lambda c: -c[0])
    fine_cfg = ScanMatcherConfig(
        linear_window=cfg.refine_window, angular_window=cfg.refine_angle, sigma=a.resolution,
        prior_weight=0.0, min_score=0.0, min_points=3)
    fine_points = _thin(walls, cfg.max_points)
    fa, fb = _Facts(a, cfg.conflict_margin), _Facts(b, cfg.conflict_margin)
    found: list[MergeResult] = []
    for _, prior in coarse[:cfg.refined]:
        fine = match_scan(fine_points, a, prior, fine_cfg)
        inliers, conflict, overlap, free = _verify(fa, fb, fine.pose, cfg)
        accepted = (inliers >= cfg.min_inliers and conflict <= cfg.max_conflict and
                    overlap >= cfg.min_wall_overlap and free >= cfg.min_free_overlap and
                    not fine.degenerate)
        found.append(MergeResult(fine.pose, float(fine.score), inliers, conflict, overlap,
                                 free, fine.degenerate, bool(accepted)))
    # The accepted match with the most agreeing wall; else the best-fitting one.
    return max(found, key=lambda m: (m.accepted, m.wall_overlap * m.inliers))


__all__ = ["MapMergeConfig", "MergeResult", "hough_spectrum", "merge_maps", "pool_grid",
           "rotation_candidates", "verify_merge", "wall_cells"]
