import math

import numpy as np
import pytest

from mjexplore.mapping.metrics import (
    accuracy,
    class_iou,
    exploration_ratio,
    iou,
    observable_ground_truth,
)
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.sim.lidar import LaserScan, LidarConfig
from mjexplore.sim.simulator import SimConfig, Simulator

F, O, U = FREE, OCCUPIED, UNKNOWN


def grid(rows):
    return GridMap(np.array(rows, np.int8)[::-1].copy(), 1.0)


def test_mapper_converges_to_ground_truth_in_box_room(box_room):
    folder, interior = box_room
    sim = Simulator(folder, SimConfig(lidar=LidarConfig(range_max=10.0)))
    gt = sim.scene.ground_truth
    mapper = OccupancyMapper.like(gt)
    reference = observable_ground_truth(gt)
    for pose in [(1.0, 1.0, 0.0), (5.4, 3.4, 2.0), (3.2, 2.2, -1.0), (1.0, 3.4, 0.5),
                 (5.4, 1.0, 3.0)]:
        mapper.integrate(sim.reset(pose))
    known = mapper.state >= 0
    assert np.array_equal(mapper.state[known], gt.data[known])  # Nothing wrong...
    assert exploration_ratio(mapper.grid, reference) > 0.995  # ...and almost all of it.
    assert iou(mapper.grid, reference) > 0.99


def test_integrate_reports_exactly_the_changed_cells():
    mapper = OccupancyMapper((40, 40), (0.0, 0.0), MapperConfig(resolution=0.1))
    # Beams close together: several return in the same cell.
    angles = np.concatenate([np.linspace(-0.5, 0.5, 11), np.linspace(-0.01, 0.01, 5)])
    ranges = np.full(16, 1.5, np.float32)
    scan = LaserScan(0.0, ranges, angles, 3.0, np.array([2.0, 2.0, 0.0]))
    before = mapper.state.copy()
    changed = mapper.integrate(scan)
    diff = np.argwhere(mapper.state != before)
    assert len(changed) == len(diff)  # No duplicates...
    assert sorted(map(tuple, changed)) == sorted(map(tuple, diff))  # ...and none missing.
    assert mapper.state[20, 35] == OCCUPIED  # (3.5, 2.0) is where the middle beam returns.
    assert mapper.state[20, 30] == FREE
    assert len(mapper.integrate(scan)) == 0  # Same scan again: nothing changes state.


def test_beam_without_return_clears_to_range_max():
    mapper = OccupancyMapper((10, 60), (0.0, 0.0), MapperConfig(resolution=0.1))
    scan = LaserScan(0.0, np.array([np.inf], np.float32), np.array([0.0]), 2.0,
                     np.array([0.55, 0.55, 0.0]))
    mapper.integrate(scan)
    row = mapper.state[5]
    assert (row[5:25] == FREE).all() and (row[27:] == UNKNOWN).all()
    assert not (mapper.state == OCCUPIED).any()


def test_a_return_closer_than_range_min_clears_nothing():
    mapper = OccupancyMapper((10, 60), (0.0, 0.0), MapperConfig(resolution=0.1))
    scan = LaserScan(0.0, np.array([-np.inf, np.nan], np.float32), np.array([0.0, 0.5]), 2.0,
                     np.array([0.55, 0.55, 0.0]))
    assert len(mapper.integrate(scan)) == 0
    assert (mapper.state == UNKNOWN).all()


def test_lidar_reports_too_close_returns_as_minus_inf(box_room):
    folder, (x0, _, _, _) = box_room
    lidar = LidarConfig(range_min=0.6, noise_std=0.0)
    sim = Simulator(folder, SimConfig(lidar=lidar))
    scan = sim.reset((x0 + 0.5, 2.2, 0.0))  # The wall behind is ~0.44 m from the lidar.
    behind = np.abs(np.abs(scan.angles) - math.pi) < 0.3
    assert np.isneginf(scan.ranges[behind]).all()
    ahead = np.abs(scan.angles) < 0.5
    assert (np.isfinite(scan.ranges[ahead]) & (scan.ranges[ahead] > 4.0)).all()
    valid = np.isfinite(scan.ranges)
    assert (scan.ranges[valid] >= lidar.range_min).all()


def test_metrics_on_hand_built_maps():
    truth = grid([[O, O, O, O, O],
                  [O, F, F, F, O],
                  [O, F, O, F, O],
                  [O, O, O, O, O]])
    # Occupied cells touching free space: all but none here (every O touches an F, the
    # corners diagonally), so the reference equals the truth.
    ref = observable_ground_truth(truth)
    assert np.array_equal(ref.data, truth.data)
    est = grid([[U, U, U, U, U],
                [O, F, F, U, U],
                [O, F, F, U, U],
                [U, U, U, U, U]])
    # Known in est and ref: 4 free/occ cells of row 1-2, cols 0-2 -> 6 cells; ref known 20.
    assert exploration_ratio(est, ref) == pytest.approx(6 / 20)
    # Free: est {(1,1),(1,2),(2,1),(2,2)}, ref {(1,1),(1,2),(1,3),(2,1),(2,3)} -> 3 / 6.
    # Occupied: est {(1,0),(2,0)}, ref has 15 occupied -> 2 / 15.
    free_iou, occ_iou = class_iou(est, ref)
    assert free_iou == pytest.approx(3 / 6)
    assert occ_iou == pytest.approx(2 / 15)
    assert iou(est, ref) == pytest.approx((3 / 6 + 2 / 15) / 2)
    # Same labels: 2 occ + 3 free = 5 known matches; no unknown cell in ref.
    assert accuracy(est, ref) == 5


def test_interior_of_thick_walls_is_not_observable():
    truth = GridMap(np.array([[F, O, O, O, F]], np.int8), 1.0)
    ref = observable_ground_truth(truth)
    assert ref.data.tolist() == [[F, O, U, O, F]]


def test_mapping_from_odometry_pose_shifts_the_map():
    mapper = OccupancyMapper((40, 40), (0.0, 0.0), MapperConfig(resolution=0.1))
    scan = LaserScan(0.0, np.array([1.0], np.float32), np.array([0.0]), 3.0,
                     np.array([1.05, 2.05, 0.0]))
    mapper.integrate(scan, sensor_pose=np.array([1.05, 2.05 + 0.5, math.pi / 2]))
    assert mapper.state[35, 10] == OCCUPIED  # 1 m "up" from (1.05, 2.55).
