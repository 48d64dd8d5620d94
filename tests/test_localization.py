import dataclasses
import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from mjexplore.errors import UserInputError
from mjexplore.mapping.localization import (
    FusedLocalizer,
    LikelihoodField,
    LocalizerConfig,
    neighbour_ranges,
)
from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.lidar import lidar_model
from mjexplore.sim.odometry import wrap_angle
from mjexplore.sim.simulator import SimConfig, Simulator

LDS01 = lidar_model("lds01")
OFFSET = np.array([0.137, -0.093, math.radians(4.3)])


def errors(pose, truth):
    return np.hypot(*(pose[:2] - truth[:2])), abs(math.degrees(wrap_angle(pose[2] - truth[2])))


@pytest.fixture(scope="module")
def maze():
    return Simulator(resolve_scene("maze"), SimConfig(dynamics="kinematic", lidar=LDS01, seed=1))


def open_poses(sim, count, seed=0):
    """Poses in the ground truth's free space at least 0.3 m from walls."""
    gt = sim.scene.ground_truth
    cells = np.argwhere(distance_transform_edt(gt.free) * gt.resolution > 0.3)
    rng = np.random.default_rng(seed)
    for rc in cells[rng.choice(len(cells), count, replace=False)]:
        x, y = gt.cell_to_world(rc)
        yield np.array([x, y, rng.uniform(-math.pi, math.pi)])


def test_field_recovers_a_known_offset_on_the_maze(maze):
    """Returns gathered at the true pose, then the estimate put off by 16 cm and 4 degrees:
    one LDS-01 scan brings it back to within a few centimetres (its range noise is 3.5 %
    of the range)."""
    gt = maze.scene.ground_truth
    config = LocalizerConfig.for_lidar(LDS01)
    for pose in open_poses(maze, 4):
        scans = [maze.reset(pose)] + [s for _ in range(10) for s in maze.step(0.2)]
        truth = maze.pose
        loc = FusedLocalizer(truth, config=config)
        for scan in scans[:-1]:  # A still robot: the estimate stays put, the map fills.
            loc.correct(scan, gt)
        assert errors(loc.pose, truth)[0] < 0.01
        loc.reset(truth + OFFSET, covariance=np.diag([0.2, 0.2, 0.1]) ** 2, keep_map=True)
        result = loc.correct(scans[-1], gt)
        assert result.accepted and result.searched  # Off the field's basin: Olson's search.
        trans, yaw = errors(loc.pose, truth)
        assert trans < 0.05 and yaw < 1.0  # From 0.16 m and 4.3 degrees.
        # The reported uncertainty covers the error and is a single noisy scan's.
        sd = np.sqrt(np.diag(loc.covariance))
        assert trans < 3 * sd[:2].max() and math.radians(yaw) < 3 * sd[2]
        assert sd[:2].max() < 0.05


def test_density_field_puts_the_wall_where_most_returns_fell():
    """Returns scattered 2 cm about a wall at x = 1 m (the LDS-01 at 0.5 m): the field is
    zero at the wall, and returns three cells off it are outliers."""
    rng = np.random.default_rng(0)
    res = 0.05
    density = np.zeros((40, 40), np.float32)
    x = 1.0 + rng.normal(0.0, 0.02, 4000)
    y = rng.uniform(0.2, 1.8, 4000)
    np.add.at(density, ((y / res).astype(int), (x / res).astype(int)), 1.0)
    field = LikelihoodField.from_density(density, res, (0.0, 0.0), np.array([1.0, 1.0]),
                                         0.9, 0.1, 0.015, 1.5)
    row = field.distance[int(round((1.0 - field.origin[1]) / res))]
    centres = field.origin[0] + (np.arange(len(row)) + 0.5) * res
    assert abs(centres[np.argmin(row)] - 1.0) < res and row.min() < 0.01
    assert np.all(row[np.abs(centres - 1.0) > 3 * res] == 0.1)
    empty = LikelihoodField.from_density(density * 0.0, res, (0.0, 0.0), np.array([1.0, 1.0]),
                                         0.9, 0.1, 0.015, 1.5)
    assert not empty.walls


def test_fused_localizer_beats_odometry_in_an_episode():
    """90 s of the maze with the LDS-01 and a typical drifting odometry, the robot mapping
    and navigating with its estimate: the odometry drifts, the fused estimate much less."""
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer

    worst = {}
    for localization in ("odometry", "scan_matching"):
        config = EpisodeConfig(max_time=90.0, localization=localization, sim=SimConfig(
            dynamics="kinematic", lidar=LDS01, odometry_error="typical"))
        episode = Episode(resolve_scene("maze"), make_explorer("nearest"), 0, config)
        worst[localization] = episode.run().metrics["pose_error_max_m"]
    assert isinstance(episode.localizer, FusedLocalizer)
    assert episode.localizer.matches > 0.95 * (episode.localizer.matches +
                                               episode.localizer.rejections)
    assert worst["odometry"] > 0.3  # The odometry drifts...
    assert worst["scan_matching"] < 0.2  # ...the fused estimate much less.


def test_without_walls_the_prediction_stays_and_its_uncertainty_grows(maze):
    loc = FusedLocalizer((1.0, 2.0, 0.5))
    before = np.diag(loc.covariance).copy()
    loc.predict((0.5, 0.0, 0.1))
    expected = np.array([1.0 + 0.5 * math.cos(0.5), 2.0 + 0.5 * math.sin(0.5), 0.6])
    assert np.allclose(loc.pose, expected)
    assert np.all(np.diag(loc.covariance) > before)
    empty = OccupancyMapper.like(maze.scene.ground_truth)
    result = loc.correct(maze.reset(maze.scene.start), empty)
    assert not result.accepted and loc.rejections == 1 and np.allclose(loc.pose, expected)


def test_config_comes_from_the_lidar_and_bad_values_are_refused():
    config = LocalizerConfig.for_lidar(LDS01)
    assert config.range_noise_rel == LDS01.noise_rel
    with pytest.raises(UserInputError, match="scan_correlation"):
        LocalizerConfig(scan_correlation=0.5)
    with pytest.raises(UserInputError):
        dataclasses.replace(config, field_sigma=0.0)
    with pytest.raises(UserInputError, match="field"):
        LocalizerConfig(field="trinary")


def test_neighbour_ranges_do_not_follow_the_beams_own_noise():
    """Walls 2 m around read with the LDS-01's 3.5 % noise: trusting each return by its own
    range (1 / range^2, a relative noise's precision) biases the walls short by about
    2 sigma^2 / R (5 mm); by the range its neighbours read, not."""
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.07, 100_000)
    ranges = 2.0 + noise
    near = neighbour_ranges(ranges)
    assert abs(np.corrcoef(noise, near)[0, 1]) < 0.01
    assert np.average(ranges, weights=ranges ** -2) < 2.0 - 0.004
    assert abs(np.average(ranges, weights=near ** -2) - 2.0) < 0.001
    ranges[[5, 6, 7]] = [np.inf, np.nan, -np.inf]  # No return, a dropout, too close.
    assert np.isfinite(neighbour_ranges(ranges)).all()
    assert np.isnan(neighbour_ranges(np.full(8, np.inf))).all()
