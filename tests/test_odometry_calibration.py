"""The fused localiser's odometry self-calibration and its sub-cell density of returns."""

import math

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.mapping.localization import FusedLocalizer, LikelihoodField, LocalizerConfig, deposit
from mjexplore.maps import GridMap
from mjexplore.sim.grid_world import GridLidar
from mjexplore.sim.lidar import lidar_model
from mjexplore.sim.odometry import compose_pose, relative_pose, wrap_angle

LDS01 = lidar_model("lds01", motion_skew=False)


def corridor(length=30.0, width=4.0, res=0.05) -> GridMap:
    """A walled corridor with pillars on alternate sides every 2.5 m (features along it)."""
    rows, cols = int(width / res), int(length / res)
    data = np.zeros((rows, cols), np.int8)
    data[:3, :] = data[-3:, :] = 100
    data[:, :3] = data[:, -3:] = 100
    for k in range(1, int(length / 2.5)):
        c = int(k * 2.5 / res)
        if k % 2:
            data[3:10, c:c + 4] = 100
        else:
            data[-10:-3, c:c + 4] = 100
    return GridMap(data, res, (0.0, 0.0, 0.0))


def route(start, steps):
    """Poses from ``start`` through relative steps (x, y, yaw)."""
    poses = [np.asarray(start, dtype=float)]
    for step in steps:
        poses.append(np.asarray(compose_pose(poses[-1], step)))
    return poses


def spin_and_drive(metres):
    turn = [(0.0, 0.0, math.radians(18.0))] * 40  # Two turns in place, 0.31 rad a scan.
    return turn + [(0.1, 0.0, 0.0)] * int(metres / 0.1) + turn


def test_self_calibration_learns_a_track_width_and_a_wheel_radius_error():
    """Odometry that turns 3 % short and veers 0.01 rad per metre (a track width and a
    wheel ratio error): the localiser learns both, and its heading ends a few times closer
    than without (in a corridor a heading error bends the walls it maps, so the scans
    alone catch it only slowly: 16 degrees off after 20 m uncalibrated)."""
    gt = corridor()
    truth = route((1.0, 2.0, 0.0), spin_and_drive(20.0))
    ends = {}
    for name, calibration in (("calibrated", (0.0, 0.03, 0.015)), ("not", (0.0, 0.0, 0.0))):
        config = LocalizerConfig.for_lidar(LDS01, calibration_std=calibration)
        loc = FusedLocalizer(truth[0], config=config)
        lidar = GridLidar(gt, LDS01, np.random.default_rng(0))
        for k in range(1, len(truth)):
            dx, dy, dth = relative_pose(truth[k - 1], truth[k])
            loc.predict((dx, dy, dth / 1.03 - 0.01 * dx))  # What the encoders report.
            loc.correct(lidar.scan(*truth[k], 0.2 * k), gt)
        ends[name] = loc
    scale, rot_scale, per_metre = ends["calibrated"].calibration
    assert scale == 1.0  # Not estimated by default.
    assert rot_scale == pytest.approx(1.03, abs=0.006)
    assert per_metre == pytest.approx(0.0103, abs=0.004)
    assert np.all(ends["calibrated"].calibration_std[1:] < [0.01, 0.005])
    assert np.all(ends["not"].calibration == (1.0, 1.0, 0.0))

    def heading_error(loc):
        return abs(math.degrees(wrap_angle(loc.pose[2] - truth[-1][2])))

    assert heading_error(ends["calibrated"]) < 4.0 < 10.0 < heading_error(ends["not"])


def test_gyro_heading_calibration_learns_the_bias():
    """A gyro heading whose bias turns it 0.015 degrees a second (three times the typical
    gyro's) and 2 % short in turns: with ``heading='imu'`` the localiser learns the bias
    per second, not per metre, and its heading ends within 1.5 degrees (over 5 degrees off
    uncalibrated)."""
    gt = corridor()
    back = [(0.0, 0.0, math.pi / 10)] * 10 + [(0.1, 0.0, 0.0)] * 200  # Turn, drive back.
    truth = route((1.0, 2.0, 0.0), (spin_and_drive(20.0) + back) * 2)  # 224 s, 80 m.
    bias, dt = math.radians(0.015), 0.2
    ends = {}
    for name, calibration in (("calibrated", (0.0, 0.03, math.radians(0.01))),
                              ("not", (0.0, 0.0, 0.0))):
        config = LocalizerConfig.for_lidar(LDS01, "imu", calibration_std=calibration)
        loc = FusedLocalizer(truth[0], config=config)
        lidar = GridLidar(gt, LDS01, np.random.default_rng(0))
        for k in range(1, len(truth)):
            dx, dy, dth = relative_pose(truth[k - 1], truth[k])
            loc.predict((dx, dy, dth / 1.02 + bias * dt), dt)  # What the gyro reports.
            loc.correct(lidar.scan(*truth[k], dt * k), gt)
        ends[name] = loc
    _, rot_scale, per_second = ends["calibrated"].calibration
    assert rot_scale == pytest.approx(1.02, abs=0.006)
    # A scan's information counts a quarter (scan_correlation 4): after 224 s about half
    # of the bias is learnt, the rest held back by its prior (0.01 deg/s).
    assert -1.3 * bias < per_second < -0.4 * bias

    def heading_error(loc):
        return abs(math.degrees(wrap_angle(loc.pose[2] - truth[-1][2])))

    assert heading_error(ends["calibrated"]) < 1.5 < 5.0 < heading_error(ends["not"])


def test_gyro_setting_lags_less_down_a_corridor():
    """Exact odometry down the corridor: each scan matched against the density its
    predecessors built. The estimate falls behind the truth (a wall's newly seen end pulls
    the scan back); with the gyro heading's lower ``min_density`` by about half as much."""
    gt = corridor()
    truth = route((1.0, 2.0, 0.0), [(0.1, 0.0, 0.0)] * 250)
    lag = {}
    for min_density in (1.5, 0.5):
        ends = []
        for seed in range(3):
            config = LocalizerConfig.for_lidar(LDS01, "imu", min_density=min_density)
            loc = FusedLocalizer(truth[0], config=config)
            lidar = GridLidar(gt, LDS01, np.random.default_rng(seed))
            loc.correct(lidar.scan(*truth[0], 0.0), gt)
            for k in range(1, len(truth)):
                loc.predict(relative_pose(truth[k - 1], truth[k]), 0.2)
                loc.correct(lidar.scan(*truth[k], 0.2 * k), gt)
            ends.append(truth[-1][0] - loc.pose[0])
        lag[min_density] = np.mean(ends) / 25.0
    assert LocalizerConfig.for_lidar(LDS01, "imu").min_density == 0.5
    assert 0.0 < lag[0.5] < 0.0025 < lag[1.5]


def test_calibration_settings_are_checked():
    with pytest.raises(UserInputError, match="calibration_std"):
        LocalizerConfig(calibration_std=(0.0, -0.1, 0.0))
    with pytest.raises(UserInputError, match="density_resolution"):
        LocalizerConfig(density_resolution=0.0)
    with pytest.raises(UserInputError, match="heading one of wheels, imu"):
        LocalizerConfig(heading="compass")


def test_deposit_keeps_a_wall_on_a_cell_boundary_in_place():
    """Returns exactly on x = 1.0 m, a boundary of 5 cm cells: shared between the cells on
    both sides, the field's zero stays on the boundary (dropped whole into the cell
    beyond, the wall moved 2.5 cm)."""
    res = 0.05
    density = np.zeros((40, 40), np.float32)
    y = np.linspace(0.2, 1.8, 400)
    points = np.column_stack([np.full_like(y, 1.0), y])
    deposit(density, res, (0.0, 0.0), np.zeros(3), points, np.ones(len(y)))
    assert density.sum() == pytest.approx(400.0, rel=1e-4)
    row = density[20]
    assert row[19] == pytest.approx(row[20]) and row[19] > 0 and row[18] == row[21] == 0
    field = LikelihoodField.from_density(density, res, (0.0, 0.0), np.array([1.0, 1.0]),
                                         0.9, 0.1, 0.015, 1.5)
    centres = field.origin[0] + (np.arange(field.distance.shape[1]) + 0.5) * res
    middle = field.distance[field.distance.shape[0] // 2]
    # The two cells about the boundary are the wall, symmetrically.
    assert np.allclose(middle[np.abs(centres - 1.0) < res], middle.min())
