import numpy as np
import pytest

from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.navigation.navigator import NavigatorConfig
from mjexplore.navigation.planner import Costmap, PlannerConfig, path_length
from mjexplore.topology.gvd import DynamicGVD


def room_with_wall():
    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[:45, 50:53] = OCCUPIED  # A wall with a gap at the top.
    return GridMap(data, 0.1)


def costmap_of(grid):
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    return Costmap(grid, gvd.distance2, PlannerConfig()), gvd


def test_path_goes_round_the_wall_and_keeps_clear():
    grid = room_with_wall()
    costmap, _ = costmap_of(grid)
    path = costmap.plan(np.array([2.0, 1.0]), np.array([8.0, 1.0]))
    assert path is not None
    assert path[:, 1].max() > 4.5  # Through the gap above the wall.
    # No shorter than the straight lines through the gap's corner at (5.15, 4.5).
    bound = 2 * np.hypot(5.15 - 2.0, 4.5 - 1.0)
    assert bound < path_length(path) < 1.3 * bound
    for x, y in path:
        r, c = grid.world_to_cell(np.array([x, y]))
        window = grid.data[r - 1:r + 2, c - 1:c + 2]
        assert (window == FREE).all()  # Never next to a wall cell.


def test_unknown_is_not_traversable_and_incremental_costs_match():
    grid = room_with_wall()
    grid.data[:, 70:] = UNKNOWN
    costmap, gvd = costmap_of(grid)
    assert costmap.plan(np.array([2.0, 1.0]), np.array([8.5, 1.0]), goal_radius=0.3) is None
    # Reveal the unknown part, update incrementally, compare with a fresh costmap.
    changed = np.flatnonzero((grid.data == UNKNOWN).reshape(-1))
    grid.data[:, 70:] = FREE
    grid.data[:, -1] = OCCUPIED
    gvd.update(grid.occupied, grid.known)
    costmap.update(np.concatenate([changed, gvd.last_changed]))
    fresh, _ = costmap_of(grid)
    assert np.array_equal(costmap.cost, fresh.cost)
    assert costmap.plan(np.array([2.0, 1.0]), np.array([8.5, 1.0])) is not None


def test_distance_field_by_buckets_equals_the_heap_search():
    rng = np.random.default_rng(4)
    grid = room_with_wall()
    for r, c in rng.integers(2, [56, 96], size=(25, 2)):  # Boxes: costs vary near walls.
        grid.data[r:r + 3, c:c + 2] = OCCUPIED
    grid.data[20:40, 75:90] = UNKNOWN
    costmap, _ = costmap_of(grid)
    for xy in ([1.5, 1.0], [8.0, 5.0], [5.2, 5.5]):
        buckets = costmap.distances_from(np.array(xy))  # Every cell: the bucket queue.
        heap = costmap.distances_from(np.array(xy), np.zeros(grid.shape, bool))  # The heap.
        reached = np.isfinite(heap)
        assert reached.sum() > 3000
        np.testing.assert_array_equal(np.isfinite(buckets), reached)
        np.testing.assert_allclose(buckets[reached], heap[reached], rtol=1e-12)


def test_distances_from_stop_at_first_target():
    grid = room_with_wall()
    costmap, _ = costmap_of(grid)
    targets = np.zeros(grid.shape, bool)
    targets[10, 20] = targets[10, 90] = True
    full = costmap.distances_from(np.array([1.5, 1.0]), targets)
    first = costmap.distances_from(np.array([1.5, 1.0]), targets, stop_after=1)
    assert np.isfinite(full[10, 90]) and np.isfinite(first[10, 20])
    assert first[10, 20] == full[10, 20]
    assert np.isinf(first[10, 90])


@pytest.mark.slow
def test_replanning_on_a_blocked_path_at_1_hz_explores_as_fast_as_at_5_hz():
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.simulator import SimConfig

    def run(navigator):
        config = EpisodeConfig(sim=SimConfig(dynamics="kinematic"), navigator=navigator)
        return Episode(resolve_scene("maze"), make_explorer("nearest"), 0, config).run().metrics

    default, every_200ms = run(NavigatorConfig()), run(
        NavigatorConfig(replan_rate_hz=5.0, replan_when_blocked=False))
    assert default["end_reason"] == every_200ms["end_reason"] == "explored"
    assert default["collisions"] == 0
    for key in ("exploration_time_s", "path_length_m"):
        assert default[key] <= 1.1 * every_200ms[key]


def test_known_cells_in_windows_are_numpys_slices():
    """The blacklist's watched windows, counted at once, read what numpy's slices of each
    window read, at the map's edges and beyond them too."""
    from mjexplore.navigation.blacklist import known_in_windows

    rng = np.random.default_rng(0)
    data = rng.choice(np.array([-1, 0, 100], np.int8), size=(40, 55))
    cells = np.concatenate([rng.integers(-15, 70, size=(300, 2)),
                            [[0, 0], [39, 54], [-40, 3], [5, -60], [39, 0]]])
    half = rng.integers(1, 12, size=len(cells))
    expected = [int((data[max(r - k, 0):r + k + 1, max(c - k, 0):c + k + 1] >= 0).sum())
                for (r, c), k in zip(cells, half)]
    assert known_in_windows(data, cells, half).tolist() == expected
