import dataclasses
import math

import numpy as np
import pytest
from conftest import box_room_grid
from scipy.ndimage import distance_transform_edt

from mjexplore.errors import UserInputError
from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.mapping.scan_matching import (
    ScanMatcherConfig,
    ScanMatchingLocalizer,
    deskew_scan,
    match_scan,
    scan_points,
    sensor_pose_of,
)
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.importer import scene_from_grid
from mjexplore.scenes.scene import write_scene
from mjexplore.sim.lidar import LaserScan, LidarConfig, lidar_model
from mjexplore.sim.odometry import odom_in_map, wrap_angle
from mjexplore.sim.simulator import SimConfig, Simulator

# Off the lattice on purpose: the refinement has to find the sub-cell part.
OFFSET = np.array([0.137, -0.093, math.radians(4.3)])


@pytest.fixture(scope="module")
def office():
    return Simulator(resolve_scene("office"), SimConfig(dynamics="kinematic",
                                                        lidar=LidarConfig(noise_std=0.01)))


def open_poses(sim, count, seed=0):
    """Poses in the ground truth's free space at least 0.3 m from walls."""
    gt = sim.scene.ground_truth
    clear = distance_transform_edt(gt.free) * gt.resolution
    cells = np.argwhere(clear > 0.3)
    rng = np.random.default_rng(seed)
    for rc in cells[rng.choice(len(cells), count, replace=False)]:
        x, y = gt.cell_to_world(rc)
        yield x, y, rng.uniform(-math.pi, math.pi)


def errors(pose, truth):
    return np.hypot(*(pose[:2] - truth[:2])), abs(math.degrees(wrap_angle(pose[2] - truth[2])))


def test_recovers_a_known_offset_on_the_office(office):
    gt = office.scene.ground_truth
    for pose in [office.scene.start, *open_poses(office, 5)]:
        scan = office.reset(pose)
        result = match_scan(scan_points(scan), gt, scan.pose + OFFSET)
        assert result.accepted and not result.degenerate
        assert result.score > 0.7
        trans, yaw = errors(result.pose, scan.pose)
        assert trans < 0.03 and yaw < 1.0
        # The reported uncertainty is of the order of the lattice (a 5 cm cell).
        assert np.sqrt(np.diag(result.covariance))[:2].max() < 0.05


def test_lds01_scan_with_dropouts_is_matched(office):
    sim = Simulator(resolve_scene("office"), SimConfig(dynamics="kinematic",
                                                       lidar=lidar_model("lds01")))
    scan = sim.reset(office.scene.start)
    assert np.isnan(scan.ranges).any() and np.isinf(scan.ranges).any()
    points = scan_points(scan)
    assert len(points) == np.isfinite(scan.ranges).sum()
    result = match_scan(points, sim.scene.ground_truth, scan.pose + OFFSET)
    trans, yaw = errors(result.pose, scan.pose)
    assert result.accepted and trans < 0.05 and yaw < 1.0


def test_branch_and_bound_finds_the_exhaustive_searchs_pose(office):
    gt = office.scene.ground_truth
    for pose in open_poses(office, 3, seed=1):
        scan = office.reset(pose)
        prior = scan.pose + OFFSET
        fast = match_scan(scan_points(scan), gt, prior, ScanMatcherConfig(refine_iterations=0))
        full = match_scan(scan_points(scan), gt, prior,
                          ScanMatcherConfig(refine_iterations=0, coarse_cells=1))
        assert np.array_equal(fast.pose, full.pose) and fast.score == full.score


@pytest.fixture(scope="module")
def corridor(tmp_path_factory):
    """A 24 x 2 m corridor: from its middle, a 6 m lidar sees no end."""
    grid, _ = box_room_grid(inner_w=24.0, inner_h=2.0)
    out = tmp_path_factory.mktemp("corridor") / "scene"
    write_scene(scene_from_grid(grid, "corridor", {"source": "test"}, start=(12.2, 1.2, 0.0)),
                out)
    return Simulator(out, SimConfig(dynamics="kinematic", lidar=LidarConfig(noise_std=0.01)))


def test_featureless_corridor_is_degenerate_along_its_axis(corridor):
    scan = corridor.reset((12.2, 1.13, 0.2))
    offset = np.array([0.2, 0.06, math.radians(3.0)])
    result = match_scan(scan_points(scan), corridor.scene.ground_truth, scan.pose + offset)
    assert result.degenerate and result.accepted
    std = np.sqrt(np.diag(result.covariance))
    assert std[0] >= 0.25 and std[1] < 0.05  # Along the axis: as wide as the window.
    error = result.pose - scan.pose
    assert error[0] == pytest.approx(offset[0], abs=1e-6)  # Along the axis: the prior kept.
    assert abs(error[1]) < 0.02 and abs(math.degrees(error[2])) < 0.5  # Across: recovered.


def test_no_match_on_an_empty_map_or_too_few_returns(office):
    scan = office.reset(office.scene.start)
    mapper = OccupancyMapper.like(office.scene.ground_truth)
    result = match_scan(scan_points(scan), mapper.grid, scan.pose + OFFSET)
    assert not result.accepted and np.array_equal(result.pose, scan.pose + OFFSET)
    few = match_scan(scan_points(scan)[:10], office.scene.ground_truth, scan.pose + OFFSET)
    assert not few.accepted


def test_deskew_moves_returns_to_the_stamps_frame():
    # Beam 10 was taken 0.1 s before the stamp, 0.1 m behind (1 m/s forward): its 2 m
    # return ahead lies 1.9 m ahead of the sensor at the stamp.
    ranges = np.full(20, np.nan, np.float32)
    ranges[10] = 2.0
    ranges[5] = np.inf
    scan = LaserScan(1.0, ranges, np.zeros(20), 3.5, np.zeros(3), time_increment=-0.01)
    straight = deskew_scan(scan, twist=(1.0, 0.0))
    assert straight.time_increment == 0.0
    assert straight.ranges[10] == pytest.approx(1.9) and straight.angles[10] == pytest.approx(0)
    assert np.isnan(straight.ranges[0]) and np.isinf(straight.ranges[5])
    # Turning in place at 1 rad/s: the beam pointed 0.1 rad clockwise of where the sensor
    # points at the stamp, from a sensor 6.4 cm behind the axle.
    turned = deskew_scan(scan, twist=(0.0, 1.0))
    point = np.array([turned.ranges[10] * math.cos(turned.angles[10]),
                      turned.ranges[10] * math.sin(turned.angles[10])])
    ox = -0.064
    back = np.array([ox * (math.cos(-0.1) - 1) + 2.0 * math.cos(-0.1),
                     ox * math.sin(-0.1) + 2.0 * math.sin(-0.1)])
    assert np.allclose(point, back)
    assert turned.angles[5] == pytest.approx(-0.05)  # No return: turned with the sensor.
    # A trajectory of odometry samples gives the same as the constant twist.
    times = np.linspace(0.0, 1.0, 21)
    poses = np.column_stack([np.zeros(21), np.zeros(21), times - 1.0])
    sampled = deskew_scan(scan, trajectory=(times, poses))
    assert np.allclose(sampled.ranges[10], turned.ranges[10])
    assert np.allclose(sampled.angles[10], turned.angles[10])


def test_deskewed_lds01_scan_fits_the_walls_while_turning():
    sim = Simulator(resolve_scene("office"), SimConfig(
        dynamics="kinematic", lidar=lidar_model("lds01", noise_std=0.0, noise_rel=0.0)))
    gt = sim.scene.ground_truth
    sim.command(0.0, 1.8)
    scans = []
    while len(scans) < 6:
        scans += sim.step(0.1)
    rows = sim.kinematics_rows
    near = []
    for scan in (scans[-1], deskew_scan(scans[-1], trajectory=(rows[:, 0], rows[:, 8:11]))):
        p = scan_points(scan)
        c, s = math.cos(scan.pose[2]), math.sin(scan.pose[2])
        xy = scan.pose[:2] + p @ np.array([[c, s], [-s, c]])
        rc = gt.world_to_cell(xy)
        dist = distance_transform_edt(~gt.occupied)[rc[:, 0], rc[:, 1]] * gt.resolution
        near.append(np.mean(dist <= 0.05))
    assert near[0] < 0.8 and near[1] > 0.99


def test_localizer_corrects_odometry_drift_while_mapping(office):
    """Mapping the office with a drifting odometry: the localiser stays near the truth."""
    from mjexplore.navigation.wander import WanderController

    sim = Simulator(resolve_scene("office"), SimConfig(
        dynamics="kinematic", lidar=LidarConfig(noise_std=0.01), odometry_error="typical",
        seed=2))
    mapper = OccupancyMapper.like(sim.scene.ground_truth)
    loc = ScanMatchingLocalizer(sim.pose, odom_pose=sim.odom_pose)
    mapper.integrate(sim.latest_scan, loc.sensor_pose)
    controller = WanderController(rng=np.random.default_rng(0))
    loc_errors, odom_errors = [], []
    while sim.time < 30.0:
        sim.command(*controller(sim.latest_scan, sim.pose))
        for scan in sim.step(0.1):
            loc.advance(sim.odom_pose)
            loc.correct(scan, mapper.grid)
            mapper.integrate(scan, loc.sensor_pose)
            loc_errors.append(np.hypot(*(loc.pose[:2] - sim.pose[:2])))
            odom = odom_in_map(sim.odom_origin, sim.odom_pose[None])[0]
            odom_errors.append(np.hypot(*(odom[:2] - sim.pose[:2])))
    assert loc.matches > 0.9 * len(loc_errors)
    assert max(odom_errors) > 0.3  # The odometry drifts...
    assert max(loc_errors) < 0.15  # ...the localiser much less.
    assert np.allclose(loc.sensor_pose, sensor_pose_of(loc.pose))
    # map -> odom puts the odometry's pose at the estimate.
    m2o = loc.map_to_odom(sim.odom_pose)
    assert np.allclose(odom_in_map(m2o, sim.odom_pose[None])[0], loc.pose)


def test_rejected_match_keeps_the_prediction(office):
    loc = ScanMatchingLocalizer((1.0, 2.0, 0.5))
    loc.predict((0.5, 0.0, 0.1))
    expected = np.array([1.0 + 0.5 * math.cos(0.5), 2.0 + 0.5 * math.sin(0.5), 0.6])
    assert np.allclose(loc.pose, expected)
    empty = OccupancyMapper.like(office.scene.ground_truth).grid
    result = loc.correct(office.reset(office.scene.start), empty)
    assert not result.accepted and loc.rejections == 1 and np.allclose(loc.pose, expected)


def test_bad_config_is_refused():
    with pytest.raises(UserInputError, match="match_gain"):
        ScanMatcherConfig(match_gain=0.0)
    with pytest.raises(UserInputError):
        dataclasses.replace(ScanMatcherConfig(), sigma=-1.0)
