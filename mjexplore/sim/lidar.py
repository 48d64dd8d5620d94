"""A 2D lidar as a fan of rays cast with one ``mj_multiRay`` call per scan.

This is the fast path (no rangefinder sensors are evaluated during physics steps): the
beam directions are fixed in the ``base_scan`` frame, rotated into the world with the
site's orientation at scan time, and cast in one ``mj_multiRay`` call.

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

import mujoco
import numpy as np

from mjexplore.errors import UserInputError

SCAN_GEOMGROUP = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)
_TILEABLE = (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_SPHERE,
             mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER,
             mujoco.mjtGeom.mjGEOM_ELLIPSOID)


@dataclasses.dataclass(frozen=True, kw_only=True)
class LidarConfig:
    """Lidar settings (defaults: the paper's simulated 360-degree, 6 m lidar).

    Attributes:
        num_beams: Beams per scan, spread evenly over ``fov``.
        fov: Field of view in radians (2 pi for a full turn).
        range_min: Readings closer than this are invalid (reported as inf), in metres.
        range_max: Readings farther than this are no return (inf), in metres.
        noise_std: Standard deviation of additive Gaussian range noise in metres.
        rate_hz: Scans per second of simulated time.
        tile_size: Side of the floor tiles the static geometry is grouped by, in metres.
    """

    num_beams: int = 360
    fov: float = 2 * np.pi
    range_min: float = 0.12
    range_max: float = 6.0
    noise_std: float = 0.0
    rate_hz: float = 10.0
    tile_size: float = 4.0

    def __post_init__(self) -> None:
        if self.num_beams < 1:
            raise UserInputError(f"lidar num_beams {self.num_beams} must be at least 1.")
        if not 0 < self.fov <= 2 * np.pi:
            raise UserInputError(f"lidar fov {self.fov} rad must be in (0, 2 pi].")
        if not 0 <= self.range_min < self.range_max:
            raise UserInputError("lidar ranges must satisfy 0 <= range_min < range_max "
                                 f"(got {self.range_min}, {self.range_max}).")
        if self.noise_std < 0 or self.rate_hz <= 0 or self.tile_size <= 0:
            raise UserInputError("lidar noise_std must be >= 0, rate_hz and tile_size > 0.")

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
        stamp: Simulated time of the scan in seconds.
        ranges: float32 ranges in metres (REP-117): ``inf`` where there is no return within
            ``range_max``, ``-inf`` where the return is closer than ``range_min``.
        angles: Beam angles in the ``base_scan`` frame in radians.
        range_max: Maximum range in metres.
        pose: (x, y, yaw) of ``base_scan`` in the world (``map``) frame at scan time.
    """

    stamp: float
    ranges: np.ndarray
    angles: np.ndarray
    range_max: float
    pose: np.ndarray


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
        for i in range(len(self.geom_ids)):
            pos, size = self._pos[i], self._size[i]
            if self._aligned[i]:
                b0 = np.maximum(pos[:2] - size[:2], lo)
                b1 = np.minimum(pos[:2] + size[:2], hi)
                if np.any(b1 <= b0):
                    continue
                spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX,
                                        pos=[*((b0 + b1) / 2), pos[2]],
                                        size=[*((b1 - b0) / 2), size[2]])
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


class Lidar:
    """Casts scans for the lidar mounted at a site of a MuJoCo model.

    Args:
        model: The compiled model.
        site: Name of the lidar frame site (``base_scan``).
        config: Lidar settings.
        rng: Generator for range noise (needed only when ``noise_std > 0``).
    """

    def __init__(self, model: mujoco.MjModel, site: str, config: LidarConfig,
                 rng: np.random.Generator | None = None) -> None:
        self.model = model
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

    def cast(self, data: mujoco.MjData) -> np.ndarray:
        """Raw distances (float64, -1 for no hit) from the site at the current state.

        ``data`` must have up-to-date kinematics (``site_xpos``, ``site_xmat``).
        """
        rot = data.site_xmat[self.site_id].reshape(3, 3)
        origin = data.site_xpos[self.site_id]
        np.matmul(rot, self._local_dirs, out=self._vec.T)
        cutoff = self.config.range_max + 0.1
        if self.static_scene.tileable:
            model, ray_data = self.static_scene.tile_model(
                self.static_scene.tile_of(origin[0], origin[1]))
        else:
            model, ray_data = self.model, data
        mujoco.mj_multiRay(model, ray_data, origin, self._vec.reshape(-1), SCAN_GEOMGROUP, 1, -1,
                           self._geomid, self._dist, None, self.config.num_beams, cutoff)
        return self._dist

    def scan(self, data: mujoco.MjData, stamp: float) -> LaserScan:
        """Casts one scan at the current state (``data`` must have up-to-date kinematics)."""
        cfg = self.config
        dist = self.cast(data)
        ranges = dist.astype(np.float32)
        if cfg.noise_std > 0:
            ranges += self.rng.normal(0.0, cfg.noise_std, size=ranges.shape).astype(np.float32)
        # REP-117: -inf for a return closer than range_min (invalid: nothing may be
        # cleared along it), +inf for none within range_max (free out to range_max).
        ranges[(dist >= 0) & (ranges < cfg.range_min)] = -np.inf
        ranges[(dist < 0) | (ranges > cfg.range_max)] = np.inf
        rot = data.site_xmat[self.site_id]
        origin = data.site_xpos[self.site_id]
        yaw = math.atan2(rot[3], rot[0])
        return LaserScan(stamp, ranges, self._angles, cfg.range_max,
                         np.array([origin[0], origin[1], yaw]))
