"""A 2D lidar as a fan of rays cast with ``mj_multiRay``, and the models of its errors.

This is the fast path (no rangefinder sensors are evaluated during physics steps): the
beam directions are fixed in the ``base_scan`` frame, rotated into the world with the
site's orientation at scan time, and cast in one ``mj_multiRay`` call.

Two models (``LidarConfig.model``, built by :func:`lidar_model`):

* ``ideal``: every beam at the scan's instant, constant Gaussian range noise.
* ``lds01``: the Turtlebot3's LDS-01 (HLS-LFCD2): 360 beams of 1 degree at 5 Hz, 0.12 to
  3.5 m; range-dependent noise (its datasheet's precision: 10 mm below 0.5 m, 3.5 % of the
  range beyond); dropouts, random per beam and certain at glancing incidence (reported as
  NaN: invalid, as REP-117 has it); and motion skew: the unit turns clockwise once per
  scan, so each beam is cast from the pose of its own instant, interpolated between the
  simulator's samples (one ``mj_multiRay`` per ``SKEW_CHUNK_S`` of beams).

The error model (:func:`measure_ranges`) takes true distances and incidence cosines from
any ray caster, so other simulators share it.

``mj_multiRay`` tests every ray against every geom of a model, so its cost grows with the
number of walls in the whole scene. The rays are therefore cast against small MuJoCo
models, one per square tile of the floor (built on first visit), each holding only the
static geometry within ``range_max`` of that tile, with long wall boxes clipped to that
neighbourhood. A hit closer than ``range_max`` from any point of the tile lies inside the
neighbourhood, so the ranges equal those cast in the full scene, at a cost that does not
grow with the scene's size. Only geom group 0 (the walls) is seen; the robot never is.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Any

import mujoco
import numpy as np

from mjexplore.errors import UserInputError

SCAN_GEOMGROUP = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)
# Motion skew: the beams of each SKEW_CHUNK_S of a scan are cast from one origin, the pose
# of the chunk's middle beam (each beam keeps its own direction). A beam's origin is then
# off by at most half a chunk's travel: 2.5 mm at 0.5 m/s, a quarter of the LDS-01's
# finest noise; one mj_multiRay call costs as much as about 35 rays.
SKEW_CHUNK_S = 0.01
_TILEABLE = (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_SPHERE,
             mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER,
             mujoco.mjtGeom.mjGEOM_ELLIPSOID)


LIDAR_MODELS = ("ideal", "lds01")


@dataclasses.dataclass(frozen=True, kw_only=True)
class LidarConfig:
    """Lidar settings (defaults: the paper's simulated 360-degree, 6 m lidar, ``ideal``).

    Build a model's settings with :func:`lidar_model`; the error fields below default to
    none.

    Attributes:
        model: 'ideal' or 'lds01': the model these settings come from (see
            :func:`lidar_model`).
        num_beams: Beams per scan, spread evenly over ``fov``.
        fov: Field of view in radians (2 pi for a full turn).
        range_min: Readings closer than this are invalid (-inf), in metres.
        range_max: Readings farther than this are no return (inf), in metres.
        noise_std: Standard deviation of additive Gaussian range noise in metres (below
            ``noise_rel_from`` when ``noise_rel`` is set).
        noise_rel: From ``noise_rel_from`` on, the noise's standard deviation is
            ``max(noise_std, noise_rel * range)`` (a fraction of the range).
        noise_rel_from: Range in metres from which ``noise_rel`` applies.
        dropout_prob: Probability that a beam returns nothing valid (NaN), any beam.
        grazing_start: Incidence angle (between the beam and the surface normal) in
            radians beyond which returns drop out, with a probability rising linearly to 1
            at ``grazing_full``; pi/2 turns incidence dropouts off.
        grazing_full: Incidence angle in radians beyond which every return drops out.
        motion_skew: Cast each beam from the pose of its own instant within the scan (a
            clockwise turn per scan period) instead of all at the scan's instant.
        rate_hz: Scans per second of simulated time.
        tile_size: Side of the floor tiles the static geometry is grouped by, in metres.
    """

    model: str = "ideal"
    num_beams: int = 360
    fov: float = 2 * np.pi
    range_min: float = 0.12
    range_max: float = 6.0
    noise_std: float = 0.0
    noise_rel: float = 0.0
    noise_rel_from: float = 0.0
    dropout_prob: float = 0.0
    grazing_start: float = np.pi / 2
    grazing_full: float = np.pi / 2
    motion_skew: bool = False
    rate_hz: float = 10.0
    tile_size: float = 4.0

    def __post_init__(self) -> None:
        if self.model not in LIDAR_MODELS:
            raise UserInputError(f"lidar model {self.model!r} is unknown: use one of "
                                 f"{', '.join(LIDAR_MODELS)}.")
        if self.num_beams < 1:
            raise UserInputError(f"lidar num_beams {self.num_beams} must be at least 1.")
        if not 0 < self.fov <= 2 * np.pi:
            raise UserInputError(f"lidar fov {self.fov} rad must be in (0, 2 pi].")
        if not 0 <= self.range_min < self.range_max < math.inf:
            raise UserInputError("lidar ranges must satisfy 0 <= range_min < range_max, finite "
                                 f"(got {self.range_min}, {self.range_max}).")
        if not (0 <= self.noise_std < math.inf and 0 < self.rate_hz < math.inf
                and 0 < self.tile_size < math.inf):
            raise UserInputError("lidar noise_std must be >= 0, rate_hz and tile_size > 0, all "
                                 f"finite (got {self.noise_std}, {self.rate_hz}, "
                                 f"{self.tile_size}).")
        if not (0 <= self.noise_rel < math.inf and 0 <= self.noise_rel_from < math.inf):
            raise UserInputError("lidar noise_rel and noise_rel_from must be finite and >= 0.")
        if not 0 <= self.dropout_prob < 1:
            raise UserInputError(f"lidar dropout_prob {self.dropout_prob} must be in [0, 1).")
        if not 0 <= self.grazing_start <= self.grazing_full <= np.pi / 2:
            raise UserInputError("lidar incidence angles must satisfy 0 <= grazing_start <= "
                                 f"grazing_full <= pi/2 (got {self.grazing_start}, "
                                 f"{self.grazing_full}).")

    @property
    def incidence_dropouts(self) -> bool:
        """Whether returns drop out at glancing incidence (the caster must give normals)."""
        return self.grazing_start < np.pi / 2

    @property
    def angles(self) -> np.ndarray:
        """Beam angles in the ``base_scan`` frame, radians, counter-clockwise from +x."""
        full_turn = np.isclose(self.fov, 2 * np.pi)
        step = self.fov / (self.num_beams if full_turn else max(self.num_beams - 1, 1))
        start = 0.0 if full_turn else -self.fov / 2
        return start + step * np.arange(self.num_beams)


@dataclasses.dataclass(frozen=True)
class LaserScan:
    """One scan, like ``sensor_msgs/LaserScan``.

    Attributes:
        stamp: Simulated time of the scan in seconds: when it is complete and delivered,
            the instant of beam 0.
        ranges: float32 ranges in metres (REP-117): ``inf`` where there is no return within
            ``range_max``, ``-inf`` where the return is closer than ``range_min``, NaN where
            the reading is invalid (a dropout). Only ``inf`` says the beam's line is free.
        angles: Beam angles in the ``base_scan`` frame in radians.
        range_max: Maximum range in metres.
        pose: (x, y, yaw) of ``base_scan`` in the world (``map``) frame at ``stamp``.
        time_increment: Seconds between beams, as ``sensor_msgs/LaserScan``'s: beam ``i``
            was taken at ``stamp + i * time_increment``. 0 when all beams are taken at once;
            negative for the LDS-01 model, which turns clockwise (beam 0 is its last).
    """

    stamp: float
    ranges: np.ndarray
    angles: np.ndarray
    range_max: float
    pose: np.ndarray
    time_increment: float = 0.0


class StaticRayScene:
    """The static geometry of geom group 0, regrouped into per-tile MuJoCo models.

    Args:
        model: The full compiled model.
        reach: Distance in metres around a tile within which geometry is kept
            (the lidar's ``range_max`` plus a margin).
        tile_size: Tile side in metres.
        max_cached: Most tile models kept in memory (least recently used are dropped).
    """

    def __init__(self, model: mujoco.MjModel, reach: float, tile_size: float,
                 max_cached: int = 256) -> None:
        self.reach = reach
        self.tile_size = tile_size
        self.max_cached = max_cached
        static = (model.geom_bodyid == 0) & (model.geom_group == 0)
        self.geom_ids = np.flatnonzero(static)
        self.tileable = bool(np.isin(model.geom_type[self.geom_ids], _TILEABLE).all())
        self._full = model
        self._type = model.geom_type[self.geom_ids].copy()
        self._size = model.geom_size[self.geom_ids].copy()
        self._pos = model.geom_pos[self.geom_ids].copy()
        self._quat = model.geom_quat[self.geom_ids].copy()
        self._rbound = model.geom_rbound[self.geom_ids].copy()
        # Boxes aligned with the map axes can be clipped to a tile's neighbourhood.
        q = self._quat
        self._aligned = (self._type == mujoco.mjtGeom.mjGEOM_BOX) & (
            np.abs(q[:, 0]) > 1 - 1e-9)
        self._tiles: collections.OrderedDict[tuple[int, int], tuple[mujoco.MjModel,
                                                                    mujoco.MjData]] = (
            collections.OrderedDict())

    def tile_of(self, x: float, y: float) -> tuple[int, int]:
        return math.floor(x / self.tile_size), math.floor(y / self.tile_size)

    def tile_model(self, key: tuple[int, int]) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The model of tile ``key`` (built on first use)."""
        entry = self._tiles.get(key)
        if entry is None:
            entry = self._build(key)
            self._tiles[key] = entry
            if len(self._tiles) > self.max_cached:
                self._tiles.popitem(last=False)
        else:
            self._tiles.move_to_end(key)
        return entry

    def _build(self, key: tuple[int, int]) -> tuple[mujoco.MjModel, mujoco.MjData]:
        lo = np.array(key, dtype=float) * self.tile_size - self.reach
        hi = lo + self.tile_size + 2 * self.reach
        spec = mujoco.MjSpec()
        spec.modelname = f"lidar_tile_{key[0]}_{key[1]}"
        # The aligned boxes clipped to the tile's neighbourhood, all at once: a tile keeps
        # few of a large map's walls, and only those are visited below.
        b0 = np.maximum(self._pos[:, :2] - self._size[:, :2], lo)
        b1 = np.minimum(self._pos[:, :2] + self._size[:, :2], hi)
        keep = ~self._aligned | (b1 > b0).all(axis=1)
        for i in np.flatnonzero(keep):
            pos, size = self._pos[i], self._size[i]
            if self._aligned[i]:
                spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX,
                                        pos=[*((b0[i] + b1[i]) / 2), pos[2]],
                                        size=[*((b1[i] - b0[i]) / 2), size[2]])
                continue
            nearest = np.clip(pos[:2], lo, hi)
            if np.linalg.norm(nearest - pos[:2]) > self._rbound[i]:
                continue
            spec.worldbody.add_geom(type=mujoco.mjtGeom(self._type[i]), pos=pos, size=size,
                                    quat=self._quat[i])
        if not spec.geoms:
            # An empty model cannot be compiled; a tiny far-away sphere never answers.
            spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[1e-3, 0, 0],
                                    pos=[*(lo - 1e3), -1e3])
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        return model, data


def ray_boxes(origin: np.ndarray, vec: np.ndarray, centres: np.ndarray, rot: np.ndarray,
              half: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays against boxes whose axes include the vertical (upright bodies): the slab
    method in each box's horizontal frame, with the hit's height checked.

    Args:
        origin: (3,) the rays' origin, metres.
        vec: (n, 3) unit ray directions.
        centres: (k, 3) box centres.
        rot: (k, 3, 3) box orientations (columns: the box axes in the world).
        half: (3,) half sizes.

    Returns:
        (n,) distance to the nearest box hit (-1 for none), (n,) the box hit (-1), and
        (n, 3) the unit normal of the face hit.
    """
    n = len(vec)
    best = np.full(n, -1.0)
    which = np.full(n, -1, np.int64)
    normal = np.zeros((n, 3))
    for b in range(len(centres)):
        axes = rot[b][:, :2]  # The box's horizontal axes in the world.
        o = (origin - centres[b]) @ axes
        d = vec @ axes
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
            t1 = (-half[:2] - o) * inv
            t2 = (half[:2] - o) * inv
        tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
        near = tmin.max(axis=1)
        far = tmax.min(axis=1)
        z = origin[2] + near * vec[:, 2] - centres[b][2]
        hit = (near <= far) & (near > 0) & (np.abs(z) <= half[2])
        hit &= (best < 0) | (near < best)
        if not hit.any():
            continue
        best[hit] = near[hit]
        which[hit] = b
        face = np.argmax(tmin[hit], axis=1)
        sign = -np.sign(d[hit, face])
        normal[hit] = sign[:, None] * axes.T[face]
    return best, which, normal


def ray_discs(origin: np.ndarray, vec: np.ndarray, centres: np.ndarray, radius: float,
              ) -> tuple[np.ndarray, np.ndarray]:
    """Rays against upright cylinders taller than the rays reach (people's discs): where
    each ray first enters a disc of ``radius`` about a centre, in the horizontal plane.

    Args:
        origin: (2,) or (3,) the rays' origin (its x, y are used), metres.
        vec: (n, 2) or (n, 3) unit ray directions (their x, y are used; the distance is
            along the whole vector).
        centres: (k, 2) disc centres.
        radius: The discs' radius, metres.

    Returns:
        (n,) distance to the nearest disc entered (inf for none; a ray from inside a disc
        does not see it), and (n, 2) the unit horizontal normal of the disc at the hit
        (zero where there is none).
    """
    rel = np.asarray(centres, float).reshape(-1, 2) - np.asarray(origin[:2], float)
    vec = vec[:, :2]
    r = radius
    horizontal = np.linalg.norm(vec, axis=1)
    b = vec @ rel.T  # (rays, discs): projection of each centre on each ray.
    c = (rel ** 2).sum(axis=1)[None, :] - r * r
    a = np.maximum(horizontal ** 2, 1e-12)[:, None]
    disc = b * b - a * c
    t = np.where(disc >= 0, (b - np.sqrt(np.maximum(disc, 0.0))) / a, np.inf)
    t = np.where(t > 0, t, np.inf).min(axis=1)
    normals = np.zeros((len(vec), 2))
    hit = np.isfinite(t)
    if hit.any():
        point = vec[hit] * t[hit, None]
        out = point[:, None, :] - rel[None, :, :]
        k = np.argmin(np.abs(np.hypot(out[..., 0], out[..., 1]) - r), axis=1)
        normals[hit] = out[np.arange(len(k)), k] / r
    return t, normals


class Lidar:
    """Casts scans for the lidar mounted at a site of a MuJoCo model.

    With ``motion_skew``, the simulator reports the robot's pose at each of its samples
    (:meth:`observe_base_pose`); the pose of each beam's instant is interpolated between
    them.

    In a team's model the lidar also sees its teammates' silhouettes (upright boxes; not
    its own robot's): the walls are cast as a robot alone's, the silhouettes by
    :func:`ray_boxes` (the geometry MuJoCo's rays would meet, at a fraction of a full-model
    ``mj_multiRay``), and the nearer return wins.

    Args:
        model: The compiled model; the site's body is the robot's free base.
        site: Name of the lidar frame site (``base_scan``, ``robot_{i}/base_scan``).
        config: Lidar settings.
        rng: Generator for range noise and dropouts (needed only when they are on).
        silhouettes: Geom ids of the teammates' silhouettes (boxes of one size).
    """

    def __init__(self, model: mujoco.MjModel, site: str, config: LidarConfig,
                 rng: np.random.Generator | None = None,
                 silhouettes: list[int] | tuple[int, ...] = ()) -> None:
        self.model = model
        # People walking in the scene (a Crowd: ``positions`` (n, 2), ``config.radius``),
        # cast as upright cylinders taller than the scan plane; None: no one.
        self.people: Any = None
        self._silhouettes = np.asarray(silhouettes, np.int64)
        self._half = model.geom_size[self._silhouettes[0]].copy() if len(silhouettes) else None
        self.config = config
        self.site_id = model.site(site).id
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.static_scene = StaticRayScene(model, config.range_max + 0.2, config.tile_size)
        self._angles = config.angles
        angles = self._angles
        self._local_dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
        n = config.num_beams
        self._vec = np.empty((n, 3))
        self._dist = np.empty(n)
        self._geomid = np.empty(n, dtype=np.int32)
        self._normal = np.empty((n, 3)) if config.incidence_dropouts else None
        self._offset = tuple(float(v) for v in model.site_pos[self.site_id][:2])
        period = 1.0 / config.rate_hz
        self.time_increment = -period / n if config.motion_skew else 0.0
        self._beam_dt = self.time_increment * np.arange(n)
        # Beams taken within SKEW_CHUNK_S of each other share an origin (one mj_multiRay).
        chunks = min(n, max(1, math.ceil(period / SKEW_CHUNK_S - 1e-9)))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        self._chunks = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self._history: collections.deque[tuple[float, float, float, float]] = (
            collections.deque())
        self._period = period

    def clear_history(self) -> None:
        """Forgets the poses observed so far (at a reset)."""
        self._history.clear()

    def observe_base_pose(self, t: float, x: float, y: float, yaw: float) -> None:
        """Records the robot base's planar pose at simulated time ``t`` (seconds, metres,
        radians, ``map`` frame), for motion skew."""
        ox, oy = self._offset
        c, s = math.cos(yaw), math.sin(yaw)
        self._history.append((t, x + c * ox - s * oy, y + s * ox + c * oy, yaw))

    def _ray_scene(self, origin: np.ndarray, data: mujoco.MjData,
                   ) -> tuple[mujoco.MjModel, mujoco.MjData]:
        if self.static_scene.tileable:
            return self.static_scene.tile_model(self.static_scene.tile_of(origin[0], origin[1]))
        return self.model, data

    def _multi_ray(self, origin: np.ndarray, data: mujoco.MjData, i0: int, i1: int) -> None:
        model, ray_data = self._ray_scene(origin, data)
        normal = None if self._normal is None else self._normal[i0:i1].reshape(-1)
        mujoco.mj_multiRay(model, ray_data, origin, self._vec[i0:i1].reshape(-1),
                           SCAN_GEOMGROUP, 1, -1, self._geomid[i0:i1], self._dist[i0:i1],
                           normal, i1 - i0, self.config.range_max + 0.1)
        if self.people is not None and len(self.people.positions):
            self._cast_people(origin, i0, i1)
        ids = self._silhouettes
        if len(ids) == 0:
            return
        assert self._half is not None  # Set whenever there are silhouettes.
        centres = data.geom_xpos[ids]
        reach = self.config.range_max + 0.3
        near = np.hypot(centres[:, 0] - origin[0], centres[:, 1] - origin[1]) <= reach
        if not near.any():
            return
        dist, which, hit_normal = ray_boxes(np.asarray(origin, float), self._vec[i0:i1],
                                            centres[near],
                                            data.geom_xmat[ids[near]].reshape(-1, 3, 3),
                                            self._half)
        walls = self._dist[i0:i1]
        nearer = (dist >= 0) & ((walls < 0) | (dist < walls))
        if nearer.any():
            walls[nearer] = dist[nearer]
            self._geomid[i0:i1][nearer] = ids[near][which[nearer]]
            if self._normal is not None:
                self._normal[i0:i1][nearer] = hit_normal[nearer]

    def _cast_people(self, origin: np.ndarray, i0: int, i1: int) -> None:
        """The people's discs (``people.positions``, radius ``people.config.radius``) met
        by beams ``i0:i1`` from ``origin`` (:func:`ray_discs`), where nearer than the
        walls."""
        centres = self.people.positions
        r = self.people.config.radius
        reach = self.config.range_max + 0.1 + r
        rel = centres - np.asarray(origin[:2], float)
        near = np.hypot(rel[:, 0], rel[:, 1]) <= reach
        if not near.any():
            return
        t, normals = ray_discs(origin, self._vec[i0:i1], centres[near], r)
        walls = self._dist[i0:i1]
        nearer = np.isfinite(t) & ((walls < 0) | (t < walls))
        if nearer.any():
            walls[nearer] = t[nearer]
            self._geomid[i0:i1][nearer] = -2  # A person (no geom of the ray scene).
            if self._normal is not None:
                self._normal[i0:i1][nearer] = np.column_stack(
                    [normals[nearer], np.zeros(int(nearer.sum()))])

    def cast(self, data: mujoco.MjData) -> np.ndarray:
        """Raw distances (float64, -1 for no hit) from the site at the current state, all
        beams at once.

        ``data`` must have up-to-date kinematics (``site_xpos``, ``site_xmat``).
        """
        rot = data.site_xmat[self.site_id].reshape(3, 3)
        np.matmul(rot, self._local_dirs, out=self._vec.T)
        self._multi_ray(data.site_xpos[self.site_id], data, 0, self.config.num_beams)
        return self._dist

    def _cast_skewed(self, data: mujoco.MjData, stamp: float) -> None:
        """Casts every beam from the pose of its instant ``stamp + i * time_increment``."""
        rot = data.site_xmat[self.site_id]
        origin = data.site_xpos[self.site_id]
        np.matmul(rot.reshape(3, 3), self._local_dirs, out=self._vec.T)
        history = self._history
        while len(history) >= 2 and history[1][0] <= stamp - self._period:
            history.popleft()
        past = [h for h in history if h[0] < stamp - 1e-9]
        past.append((stamp, float(origin[0]), float(origin[1]), math.atan2(rot[3], rot[0])))
        t, x, y, yaw = np.array(past).T
        turn = np.diff(yaw)
        yaw[1:] = yaw[0] + np.cumsum((turn + np.pi) % (2 * np.pi) - np.pi)  # Unwrapped.
        when = stamp + self._beam_dt
        dx = np.interp(when, t, x) - x[-1]
        dy = np.interp(when, t, y) - y[-1]
        dyaw = np.interp(when, t, yaw) - yaw[-1]
        c, s = np.cos(dyaw), np.sin(dyaw)
        vx, vy = self._vec[:, 0].copy(), self._vec[:, 1]
        self._vec[:, 0] = c * vx - s * vy
        self._vec[:, 1] = s * vx + c * vy
        for i0, i1 in self._chunks:
            mid = (i0 + i1 - 1) // 2
            self._multi_ray(np.array([origin[0] + dx[mid], origin[1] + dy[mid], origin[2]]),
                            data, i0, i1)

    def scan(self, data: mujoco.MjData, stamp: float) -> LaserScan:
        """Casts one scan at the current state (``data`` must have up-to-date kinematics)."""
        cfg = self.config
        if cfg.motion_skew:
            self._cast_skewed(data, stamp)
        else:
            self.cast(data)
        cos_incidence = None
        if self._normal is not None:
            cos_incidence = np.abs(np.einsum("ij,ij->i", self._vec, self._normal))
        ranges = measure_ranges(self._dist, cfg, self.rng, cos_incidence)
        rot = data.site_xmat[self.site_id]
        origin = data.site_xpos[self.site_id]
        yaw = math.atan2(rot[3], rot[0])
        return LaserScan(stamp, ranges, self._angles, cfg.range_max,
                         np.array([origin[0], origin[1], yaw]), self.time_increment)


# The Turtlebot3's LDS-01 (HLS-LFCD2; ROBOTIS e-Manual, LDS-01 specifications; the
# hls_lfcd_lds_driver's scan). Dropout rates are not published: 1 % per beam, and returns
# fading from 70 degrees of incidence to none at 85, are this model's assumptions.
LDS01 = LidarConfig(model="lds01", num_beams=360, fov=2 * np.pi, range_min=0.12,
                    range_max=3.5, noise_std=0.010, noise_rel=0.035, noise_rel_from=0.5,
                    dropout_prob=0.01, grazing_start=math.radians(70.0),
                    grazing_full=math.radians(85.0), motion_skew=True, rate_hz=5.0)


def lidar_model(name: str = "ideal", **overrides) -> LidarConfig:
    """The settings of a lidar model, with some replaced.

    Args:
        name: 'ideal' (:class:`LidarConfig`'s defaults) or 'lds01' (:data:`LDS01`).
        **overrides: :class:`LidarConfig` fields to replace (e.g. ``range_max``).

    Raises:
        UserInputError: unknown model or invalid settings.
    """
    if name == "ideal":
        return LidarConfig(**overrides)
    if name == "lds01":
        return dataclasses.replace(LDS01, **overrides)
    raise UserInputError(f"lidar model {name!r} is unknown: use one of "
                         f"{', '.join(LIDAR_MODELS)}.")


def range_noise_std(dist: np.ndarray, noise_std: float, noise_rel: float = 0.0,
                    noise_rel_from: float = 0.0) -> np.ndarray:
    """Standard deviation of the range noise at each distance, metres: ``noise_std``, and
    from ``noise_rel_from`` on at least ``noise_rel`` times the distance (a
    :class:`LidarConfig`'s fields of the same names)."""
    dist = np.asarray(dist, dtype=np.float64)
    return np.where(dist >= noise_rel_from, np.maximum(noise_rel * dist, noise_std),
                    float(noise_std))


def dropout_probability(config: LidarConfig, cos_incidence: np.ndarray | None,
                        n: int) -> np.ndarray:
    """Probability that each of ``n`` beams drops out.

    Args:
        config: Lidar settings.
        cos_incidence: |cos| of each beam's angle to the surface normal at its hit (1 for
            beams that hit nothing), or None for normal incidence everywhere.
        n: Number of beams.
    """
    p = np.full(n, float(config.dropout_prob))
    if cos_incidence is not None and config.incidence_dropouts:
        angle = np.arccos(np.clip(cos_incidence, 0.0, 1.0))
        span = config.grazing_full - config.grazing_start
        if span > 0:
            grazing = np.clip((angle - config.grazing_start) / span, 0.0, 1.0)
        else:
            grazing = (angle > config.grazing_start).astype(float)
        p = 1.0 - (1.0 - p) * (1.0 - grazing)
    return p


def measure_ranges(dist: np.ndarray, config: LidarConfig, rng: np.random.Generator,
                   cos_incidence: np.ndarray | None = None) -> np.ndarray:
    """Readings of a scan from true distances: noise, range limits and dropouts.

    Random draws, in this order: one normal per beam when there is noise, one uniform per
    beam when there are dropouts; the ideal model draws exactly as it always has.

    Args:
        dist: True distance of each beam's hit in metres; negative or inf for no hit.
        config: Lidar settings.
        rng: Generator for noise and dropouts.
        cos_incidence: |cos| of each beam's angle to the surface normal at its hit (any
            value for beams that hit nothing), or None for normal incidence everywhere.

    Returns:
        float32 ranges as :attr:`LaserScan.ranges` has them (REP-117: -inf closer than
        ``range_min``, inf no return within ``range_max``, NaN dropped out).
    """
    cfg = config
    hit = (dist >= 0) & np.isfinite(dist)
    ranges = dist.astype(np.float32)
    if cfg.noise_rel > 0:
        std = range_noise_std(np.where(hit, dist, 0.0), cfg.noise_std, cfg.noise_rel,
                              cfg.noise_rel_from)
        ranges += (rng.normal(0.0, 1.0, size=ranges.shape) * std).astype(np.float32)
    elif cfg.noise_std > 0:
        ranges += rng.normal(0.0, cfg.noise_std, size=ranges.shape).astype(np.float32)
    # REP-117: -inf for a return closer than range_min (invalid: nothing may be
    # cleared along it), +inf for none within range_max (free out to range_max).
    ranges[hit & (ranges < cfg.range_min)] = -np.inf
    ranges[~hit | (ranges > cfg.range_max)] = np.inf
    if cfg.dropout_prob > 0 or cfg.incidence_dropouts:
        if cos_incidence is not None:
            cos_incidence = np.where(hit, cos_incidence, 1.0)
        p = dropout_probability(cfg, cos_incidence, len(ranges))
        ranges[rng.random(len(ranges)) < p] = np.nan
    return ranges
