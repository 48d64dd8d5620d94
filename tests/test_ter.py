import math

import numpy as np
import pytest

from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.navigation.wander import WanderController
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import Simulator
from mjexplore.topology.graph import segment_is_free
from mjexplore.topology.pipeline import TopologyConfig, TopologyTracker
from mjexplore.topology.ter import FRONTIER_FLAG, OTHER_FLAG, ROBOT_FLAG, TerConfig


@pytest.fixture(scope="module")
def explored_office():
    """The office after 60 s of wandering: mapper, tracker and the final pose."""
    sim = Simulator(resolve_scene("office"))
    mapper = OccupancyMapper.like(sim.scene.ground_truth)
    tracker = TopologyTracker(mapper.state.shape)
    tracker.observe(mapper.grid, mapper.integrate(sim.latest_scan))
    controller = WanderController(rng=np.random.default_rng(0))
    for _ in range(600):
        sim.command(*controller(sim.latest_scan, sim.pose))
        for scan in sim.step(0.1):
            tracker.observe(mapper.grid, mapper.integrate(scan))
    return mapper, tracker, sim.pose


def test_every_ter_edge_is_collision_free_on_the_known_map(explored_office):
    mapper, tracker, pose = explored_office
    grid = mapper.grid
    ter, frontiers, gains = tracker.ter(grid, pose)
    assert len(frontiers) > 0 and len(ter.edges) > 10
    free = grid.free
    for a, b in ter.edges:
        ca = (ter.positions[a] - grid.origin[:2]) / grid.resolution - 0.5
        cb = (ter.positions[b] - grid.origin[:2]) / grid.resolution - 0.5
        assert segment_is_free(free, ca[::-1], cb[::-1])
    assert np.allclose(ter.lengths, np.linalg.norm(
        ter.positions[ter.edges[:, 0]] - ter.positions[ter.edges[:, 1]], axis=1))
    # GVD sides respect the maximum side length (frontier/robot links may be longer).
    gvd_edges = (ter.flags[ter.edges] == OTHER_FLAG).all(axis=1)
    assert ter.lengths[gvd_edges].max() <= 2.0 + 1e-6


def test_ter_is_connected_and_has_one_robot(explored_office):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    mapper, tracker, pose = explored_office
    ter, _, _ = tracker.ter(mapper.grid, pose)
    n = len(ter.positions)
    adjacency = coo_matrix((np.ones(len(ter.edges)), tuple(ter.edges.T)), shape=(n, n))
    _, labels = connected_components(adjacency, directed=False)
    assert (ter.flags == ROBOT_FLAG).sum() == 1
    # Every frontier node reaches the robot through the graph.
    assert (labels[ter.flags == FRONTIER_FLAG] == labels[ter.robot]).all()


def test_node_features(explored_office):
    mapper, tracker, pose = explored_office
    ter, frontiers, gains = tracker.ter(mapper.grid, pose)
    f = ter.features
    assert f.shape == (len(ter.positions), 6)
    rel = ter.positions - pose[:2]
    assert np.allclose(f[:, 4], np.hypot(rel[:, 0], rel[:, 1]))  # D
    # (px, py) is the position in the robot frame: rotating back gives the map offset.
    c, s = math.cos(pose[2]), math.sin(pose[2])
    back = np.column_stack([c * f[:, 0] - s * f[:, 1], s * f[:, 0] + c * f[:, 1]])
    assert np.allclose(back, rel)
    assert np.allclose(f[:, 3], np.arctan2(f[:, 1], f[:, 0]))  # phi_diff
    assert set(np.unique(f[:, 5])) <= {ROBOT_FLAG, FRONTIER_FLAG, OTHER_FLAG}
    fnodes = ter.flags == FRONTIER_FLAG
    assert np.allclose(f[fnodes, 2], gains[ter.frontier_index[fnodes]])
    # Other nodes: discounted gain, never above the best frontier's, zero beyond D_gain.
    others = ~fnodes
    assert (f[others, 2] <= gains.max() + 1e-12).all()
    far = np.array([np.linalg.norm(ter.positions[fnodes] - p, axis=1).min() >= 5.0
                    for p in ter.positions[others]])
    assert (f[others, 2][far] == 0).all()


def test_padded_arrays(explored_office):
    mapper, tracker, pose = explored_office
    ter, _, _ = tracker.ter(mapper.grid, pose)
    cfg = TerConfig(max_nodes=64, max_neighbours=4)
    p = ter.padded(cfg)
    n = min(len(ter.positions), 64)
    assert p.node_features.shape == (64, 6) and p.node_features.dtype == np.float32
    assert p.node_mask.sum() == n
    assert p.action_mask.sum() == (ter.flags == FRONTIER_FLAG).sum()
    assert not p.action_mask[p.node_mask == 0].any()
    assert np.isfinite(p.node_features).all() and np.isfinite(p.edge_lengths).all()
    # Every neighbour slot points at a kept node joined by a real TER edge of that length.
    kept = p.node_positions[p.node_mask == 1]
    for u in range(64):
        for k in np.flatnonzero(p.neighbour_mask[u]):
            v = p.neighbours[u, k]
            assert p.node_mask[v] == 1
            length = np.linalg.norm(p.node_positions[u] - p.node_positions[v])
            assert p.edge_lengths[u, k] == pytest.approx(length, abs=1e-3)
    assert len(kept) == n
    # Truncation keeps the robot and the frontiers first.
    small = ter.padded(TerConfig(max_nodes=10, max_neighbours=4))
    kept_flags = small.node_features[small.node_mask == 1, 5]
    assert (kept_flags == ROBOT_FLAG).sum() == 1


def test_tracker_with_ground_truth_gain(box_room):
    from mjexplore.sim.lidar import LidarConfig
    from mjexplore.sim.simulator import SimConfig
    from mjexplore.topology.frontiers import information_gain

    folder, _ = box_room
    sim = Simulator(folder, SimConfig(lidar=LidarConfig(range_max=2.0)))  # A partial view.
    gt = sim.scene.ground_truth
    mapper = OccupancyMapper.like(gt)
    tracker = TopologyTracker(mapper.state.shape, TopologyConfig(gain="ground_truth"), gt)
    scan = sim.reset((1.0, 2.2, 0.0))
    tracker.observe(mapper.grid, mapper.integrate(scan))
    ter, frontiers, gains = tracker.ter(mapper.grid, sim.pose)
    assert len(frontiers) > 0 and (gains > 0).all()
    assert np.allclose(gains, information_gain(mapper.grid, gt, frontiers))
    fnodes = ter.flags == FRONTIER_FLAG
    assert np.allclose(ter.features[fnodes, 2], gains[ter.frontier_index[fnodes]])
    assert (ter.flags == ROBOT_FLAG).sum() == 1
    with pytest.raises(ValueError):
        TopologyTracker((5, 5), TopologyConfig(gain="ground_truth"))


def test_links_go_to_the_nearest_target_a_free_segment_reaches(explored_office):
    from mjexplore.topology.ter import _link

    mapper, tracker, pose = explored_office
    grid = mapper.grid
    free = grid.free
    targets = grid.cell_to_world(tracker.graph(grid, free).positions)
    free_cells = np.argwhere(free)
    some = free_cells[np.random.default_rng(0).choice(len(free_cells), 200, replace=False)]
    points = np.concatenate([[f.goal for f in tracker.frontiers(grid)], [pose[:2]],
                             grid.cell_to_world(some)])
    targets = np.concatenate([targets, targets[:3]])  # Exact ties: the lower index wins.

    def reference(point, k):
        cell = lambda xy: ((xy - grid.origin[:2]) / grid.resolution - 0.5)[::-1]  # noqa: E731
        for i in np.argsort(np.linalg.norm(targets - point, axis=1), kind="stable")[:k]:
            if segment_is_free(free, cell(point), cell(targets[i])):
                return i
        return -1

    for k in (1, 3, 8):
        expected = [reference(p, k) for p in points]
        assert _link(free, grid, points, targets, k).tolist() == expected
    assert -1 in [reference(p, 1) for p in points]  # Some nearest targets are hidden.
    assert (_link(free, grid, points, targets[:0], 8) == -1).all()


def test_frontiers_are_found_once_per_map_state(explored_office):
    from mjexplore.topology.frontiers import find_frontiers

    mapper, _, pose = explored_office
    tracker = TopologyTracker(mapper.state.shape)
    tracker.observe(mapper.grid)
    first = tracker.frontiers(mapper.grid)
    assert tracker.frontiers(mapper.grid) is first
    assert tracker.ter(mapper.grid, pose)[1] is first
    tracker.observe(mapper.grid, np.zeros((0, 2), np.int64))
    again = tracker.frontiers(mapper.grid)
    assert again is not first
    assert [f.goal.tolist() for f in again] == [f.goal.tolist() for f in find_frontiers(
        mapper.grid)]
    assert tracker.frontiers(mapper.grid) is again
    copy = mapper.grid.data.copy()
    copy[copy < 0] = 0  # Another map: everything known, no frontier left.
    assert tracker.frontiers(type(mapper.grid)(copy, mapper.grid.resolution)) == []
