"""The LDS-01's beams are cast over its 0.2 s rotation: every scan the robot maps must be
posed beam by beam at the beams' own instants (de-skewed), in every localisation mode."""

import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.explorers import make_explorer
from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.mapping.scan_matching import deskew_scan, scan_points
from mjexplore.maps import OCCUPIED, is_occupied
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.lidar import lidar_model
from mjexplore.sim.simulator import SimConfig, Simulator

# The LDS-01 without noise or dropouts: every return lies exactly on a wall.
EXACT_LDS01 = lidar_model("lds01", noise_std=0.0, noise_rel=0.0, dropout_prob=0.0,
                          grazing_start=math.pi / 2, grazing_full=math.pi / 2)


class ScanLog:
    def __init__(self):
        self.scans = []

    def on_scan(self, episode, scan):
        self.scans.append(scan)

    def on_decision(self, episode, state):
        pass

    def on_step(self, episode):
        pass


@pytest.fixture(scope="module")
def maze():
    return resolve_scene("maze")


def test_ground_truth_mode_maps_the_beams_where_they_were_cast(maze):
    """40 s of the maze at up to 0.5 m/s: mapped at the true poses beam by beam, no wall
    lands in the open (the raw scans, posed at their stamps, put walls up to 10 cm off)."""
    log = ScanLog()
    config = EpisodeConfig(max_time=40.0, sim=SimConfig(dynamics="kinematic",
                                                        lidar=EXACT_LDS01))
    episode = Episode(maze, make_explorer("nearest"), 0, config, observer=log)
    episode.run()
    gt = maze.ground_truth
    open_space = distance_transform_edt(~is_occupied(gt.data)) > 1.5  # Cells off walls.

    def walls_in_the_open(state):
        return int(((state == OCCUPIED) & open_space).sum())

    raw = OccupancyMapper.like(gt)
    for scan in log.scans:
        raw.integrate(scan)
    assert walls_in_the_open(raw.state) > 20  # The skew is there to undo...
    assert walls_in_the_open(episode.mapper.state) == 0  # ...and the episode undoes it.


def test_deskewed_returns_lie_on_the_walls_at_the_stamp(maze):
    """Driving straight (along x) at 0.5 m/s with exact odometry, each scan de-skewed along
    the odometry's samples (as the episode does) and posed at the true pose of its stamp
    puts its returns on the walls across the direction of travel to within 3 mm: the
    scan's stamp, its beams' instants and the odometry's samples agree (10 ms off would put
    them 5 mm off; the raw scan's are up to 10 cm off)."""
    sim = Simulator(maze, SimConfig(dynamics="kinematic", lidar=EXACT_LDS01))
    gt = maze.ground_truth
    res = gt.resolution
    clear = distance_transform_edt(gt.free) * res > 0.3
    run = int(3.0 / res)
    start = next(rc for rc in np.argwhere(clear) if rc[1] + run < gt.shape[1] and
                 clear[rc[0], rc[1]:rc[1] + run].all())
    sim.reset((*gt.cell_to_world(start), 0.0))
    walls = is_occupied(gt.data)

    def wall(x, y):
        return walls[np.floor((y - gt.origin[1]) / res).astype(int),
                     np.floor((x - gt.origin[0]) / res).astype(int)]

    offsets = []
    for _ in range(100):
        sim.command(0.5, 0.0)
        for scan in sim.step(0.05):
            rows = sim.kinematics_rows
            if rows[-1, 1] < 0.45:
                continue  # Still accelerating.
            scan = deskew_scan(scan, trajectory=(rows[-10:, 0], rows[-10:, 8:11]))
            x, y, yaw = scan.pose  # base_scan's true pose at the stamp.
            pts = scan_points(scan)
            c, s = math.cos(yaw), math.sin(yaw)
            px, py = x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]
            # Returns on a face across x (wall on one side, open on the other; not a
            # corner), whose faces lie on cell boundaries.
            across = ((wall(px - 0.02, py) != wall(px + 0.02, py)) &
                      (wall(px, py - 0.02) == wall(px, py + 0.02)))
            face = np.round((px[across] - gt.origin[0]) / res) * res + gt.origin[0]
            offsets.append(px[across] - face)
    offsets = np.concatenate(offsets)
    assert len(offsets) > 100
    assert np.all(np.abs(offsets) < 0.003)
