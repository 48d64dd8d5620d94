import math

import numpy as np
import pytest

from mjexplore.sim.lidar import LidarConfig
from mjexplore.sim.simulator import SimConfig, Simulator


def analytic_ranges(origin, heading, angles, interior):
    """Distances from a point inside a rectangle to its boundary along each beam."""
    x0, y0, x1, y1 = interior
    out = []
    for a in angles:
        dx, dy = math.cos(heading + a), math.sin(heading + a)
        ts = []
        if dx > 1e-12:
            ts.append((x1 - origin[0]) / dx)
        if dx < -1e-12:
            ts.append((x0 - origin[0]) / dx)
        if dy > 1e-12:
            ts.append((y1 - origin[1]) / dy)
        if dy < -1e-12:
            ts.append((y0 - origin[1]) / dy)
        out.append(min(ts))
    return np.array(out)


@pytest.mark.parametrize("pose", [(1.0, 2.2, 0.0), (3.1, 1.7, 0.7), (5.0, 3.0, -2.5)])
def test_ranges_in_box_room_match_analytic_distances(box_room, pose):
    folder, interior = box_room
    sim = Simulator(folder, SimConfig(lidar=LidarConfig(range_max=10.0)))
    scan = sim.reset(pose)
    x, y, yaw = sim.pose
    sx, sy = scan.pose[:2]
    # base_scan sits 0.064 m behind base_link.
    assert sx == pytest.approx(x - 0.064 * math.cos(yaw), abs=1e-4)
    assert sy == pytest.approx(y - 0.064 * math.sin(yaw), abs=1e-4)
    expected = analytic_ranges((sx, sy), scan.pose[2], scan.angles, interior)
    assert scan.ranges.shape == (360,)
    assert np.all(np.isfinite(scan.ranges))  # No beam escapes, none hits the robot.
    assert np.abs(scan.ranges - expected).max() < 0.01


def test_range_limits_and_noise(box_room):
    folder, interior = box_room
    sim = Simulator(folder, SimConfig(lidar=LidarConfig(range_max=3.0)))
    scan = sim.reset((1.0, 2.2, 0.0))
    expected = analytic_ranges(scan.pose[:2], scan.pose[2], scan.angles, interior)
    assert np.array_equal(np.isinf(scan.ranges), expected > 3.0)

    noisy = Simulator(folder, SimConfig(lidar=LidarConfig(range_max=10.0, noise_std=0.02),
                                        seed=3))
    errors = []
    for _ in range(10):
        noisy.step(0.1)
        s = noisy.latest_scan
        errors.append(s.ranges - analytic_ranges(s.pose[:2], s.pose[2], s.angles, interior))
    errors = np.concatenate(errors)
    assert abs(errors.mean()) < 0.003
    assert 0.018 < errors.std() < 0.022


def test_tiled_ray_scene_equals_full_scene_in_office():
    import mujoco

    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.lidar import SCAN_GEOMGROUP

    sim = Simulator(resolve_scene("office"))
    grid = sim.scene.ground_truth
    rows, cols = np.nonzero(grid.free)
    rng = np.random.default_rng(0)
    m, d = sim.model, sim.data
    full = np.empty(360)
    geomid = np.empty(360, np.int32)
    for k in rng.integers(len(rows), size=60):
        x, y = grid.cell_to_world(np.array([rows[k], cols[k]]))
        sim.reset((x, y, rng.uniform(-math.pi, math.pi)))
        tiled = sim.lidar.cast(d).copy()
        site = sim.lidar.site_id
        mujoco.mj_multiRay(m, d, d.site_xpos[site], sim.lidar._vec.reshape(-1).copy(),
                           SCAN_GEOMGROUP, 1, -1, geomid, full, None, 360, 6.1)
        in_range = (full >= 0) & (full < 6.0)
        assert np.array_equal(in_range, (tiled >= 0) & (tiled < 6.0))
        assert np.abs(tiled[in_range] - full[in_range]).max() < 1e-9


def _tile_geoms_one_by_one(scene, key):
    """(type, pos, size) of the geoms a tile keeps, each geom tested on its own (the
    per-geom loop the vectorised tile build replaced)."""
    lo = np.array(key, dtype=float) * scene.tile_size - scene.reach
    hi = lo + scene.tile_size + 2 * scene.reach
    kept = []
    for i in range(len(scene.geom_ids)):
        pos, size = scene._pos[i], scene._size[i]
        if scene._aligned[i]:
            b0 = np.maximum(pos[:2] - size[:2], lo)
            b1 = np.minimum(pos[:2] + size[:2], hi)
            if not np.any(b1 <= b0):
                kept.append((6, [*((b0 + b1) / 2), pos[2]], [*((b1 - b0) / 2), size[2]]))
        elif np.linalg.norm(np.clip(pos[:2], lo, hi) - pos[:2]) <= scene._rbound[i]:
            kept.append((int(scene._type[i]), list(pos), list(size)))
    return kept


def test_tile_build_keeps_the_geoms_a_per_geom_test_keeps():
    import mujoco

    from mjexplore.sim.lidar import StaticRayScene

    spec = mujoco.MjSpec()
    rng = np.random.default_rng(3)
    for _ in range(120):  # Aligned wall boxes over a 40 m square, some long.
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX,
                                pos=[*rng.uniform(0, 40, 2), 0.5],
                                size=[*rng.uniform(0.05, 6.0, 2), 0.5])
    for _ in range(20):  # Rotated boxes and cylinders: kept by their bounding spheres.
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=[*rng.uniform(0, 40, 2), 0.5],
                                size=[0.3, 0.1, 0.5], euler=[0, 0, rng.uniform(0.1, 1.4)])
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                                pos=[*rng.uniform(0, 40, 2), 0.5], size=[0.2, 0.5, 0])
    scene = StaticRayScene(spec.compile(), reach=3.7, tile_size=2.0)
    for key in [(0, 0), (3, 7), (10, 10), (19, 2), (-2, -2), (25, 25)]:
        tile, _ = scene.tile_model(key)
        expected = _tile_geoms_one_by_one(scene, key)
        if not expected:
            assert tile.ngeom == 1 and tile.geom_pos[0, 2] < -100  # The far-away dummy.
            continue
        assert tile.ngeom == len(expected)
        assert np.array_equal(tile.geom_type, [t for t, _, _ in expected])
        assert np.array_equal(tile.geom_pos, np.array([p for _, p, _ in expected]))
        assert np.array_equal(tile.geom_size, np.array([s for _, _, s in expected]))
