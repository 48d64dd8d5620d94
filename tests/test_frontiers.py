import numpy as np
import pytest

from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.topology.frontiers import (
    estimated_information_gain,
    find_frontiers,
    frontier_mask,
    information_gain,
)

F, O, U = FREE, OCCUPIED, UNKNOWN


def grid(rows, res=1.0):
    """Rows as printed (top row = highest y)."""
    return GridMap(np.array(rows, np.int8)[::-1].copy(), res)


def test_frontier_cells_are_unknown_with_free_4_neighbour():
    g = grid([[U, U, U, U],
              [U, F, F, U],
              [U, F, O, U],
              [U, U, U, U]])
    mask = frontier_mask(g)[::-1]  # Back to printed order.
    expected = np.array([[0, 1, 1, 0],
                         [1, 0, 0, 1],
                         [1, 0, 0, 0],
                         [0, 1, 0, 0]], bool)
    assert np.array_equal(mask, expected)


def test_clusters_and_goals():
    g = grid([[O, O, O, O, O, O, O],
              [U, F, F, F, F, F, U],
              [U, F, F, F, F, F, U],
              [O, O, O, O, O, O, O]])
    fronts = find_frontiers(g, min_size=2)
    assert sorted(f.size for f in fronts) == [2, 2]
    for f in fronts:
        r, c = f.goal_cell
        assert g.data[r, c] == FREE
        assert min(abs(c - f.cells[:, 1])) == 1  # The goal is next to the frontier.
    assert find_frontiers(g, min_size=3) == []


def test_long_frontiers_are_split():
    data = np.full((5, 60), FREE, np.int8)
    data[4, :] = UNKNOWN  # One 60-cell frontier along the top edge.
    g = GridMap(data, 0.1)
    fronts = find_frontiers(g, max_length=2.0)
    assert len(fronts) == 3 and sum(f.size for f in fronts) == 60


def test_information_gain_matches_hand_computation():
    # Ground truth: a left room (explored) and, beyond its frontier, two unexplored rooms:
    # one of 6 free cells joined to the frontier, one of 4 cells cut off by a wall.
    truth = grid([[O, O, O, O, O, O, O, O],
                  [O, F, F, F, F, O, F, O],
                  [O, F, F, F, F, O, F, O],
                  [O, F, F, F, F, O, F, O],
                  [O, O, O, O, O, O, F, O],
                  [O, O, O, O, O, O, O, O]])
    est = grid([[O, O, O, U, U, U, U, U],
                [O, F, F, U, U, U, U, U],
                [O, F, F, U, U, U, U, U],
                [O, F, F, U, U, U, U, U],
                [O, O, O, U, U, U, U, U],
                [U, U, U, U, U, U, U, U]])
    fronts = find_frontiers(est, min_size=1, max_length=10.0)
    assert len(fronts) == 1 and fronts[0].size == 3
    gains = information_gain(est, truth, fronts)
    total_free = 12 + 4
    # The frontier column (x = 3) is itself unexplored free space, joined with x = 4: 6
    # cells. The right room (4 cells) is separated by the wall at x = 5.
    assert gains[0] == pytest.approx(6 / total_free)


def test_estimated_gain_is_unknown_share_of_window():
    data = np.full((21, 21), FREE, np.int8)
    data[:, 11:] = UNKNOWN
    g = GridMap(data, 0.1)
    fronts = find_frontiers(g, min_size=1, max_length=10.0)
    assert len(fronts) == 1
    row, col = g.world_to_cell(fronts[0].centre)
    assert (row, col) == (10, 11)
    gain = estimated_information_gain(g, fronts, radius=0.5)
    # The 11 x 11 window spans columns 6..16, of which 11..16 (6 columns) are unknown.
    assert gain[0] == pytest.approx(6 * 11 / 121)


def test_window_counts_match_the_clipped_windows():
    from mjexplore.maps import window_counts

    rng = np.random.default_rng(0)
    mask = rng.random((23, 31)) < 0.3
    cells = np.column_stack([rng.integers(0, 23, 200), rng.integers(0, 31, 200)])
    cells[:4] = [(0, 0), (22, 30), (0, 30), (22, 0)]  # Windows cut by every border.
    for half in (1, 3, 40):
        expected = [mask[max(r - half, 0):r + half + 1, max(c - half, 0):c + half + 1].sum()
                    for r, c in cells]
        assert window_counts(mask, cells, half).tolist() == expected


def _random_partial_map(seed: int, edge: bool) -> GridMap:
    """A partly explored map: free rooms inside walls, unknown elsewhere; with ``edge`` the
    free space touches the map's border."""
    rng = np.random.default_rng(seed)
    data = np.full((120, 160), UNKNOWN, np.int8)
    for _ in range(6):
        r, c = rng.integers(0, 100), rng.integers(0, 140)
        data[r:r + rng.integers(5, 30), c:c + rng.integers(5, 40)] = FREE
    data[rng.random(data.shape) < 0.02] = OCCUPIED
    if edge:
        data[0:10, 0:30] = FREE
    return GridMap(data, 0.05)


@pytest.mark.parametrize("seed,edge", [(0, False), (1, True), (2, False), (3, True)])
def test_frontiers_of_the_free_box_are_the_whole_maps(seed, edge, monkeypatch):
    from mjexplore.topology import frontiers

    grid = _random_partial_map(seed, edge)
    boxed = find_frontiers(grid)
    monkeypatch.setattr(frontiers, "_free_box", lambda free: (slice(0, free.shape[0]),
                                                             slice(0, free.shape[1])))
    whole = find_frontiers(grid)
    assert len(boxed) == len(whole) > 3
    for a, b in zip(boxed, whole):
        assert np.array_equal(a.cells, b.cells) and a.goal_cell == b.goal_cell
        assert np.array_equal(a.centre, b.centre) and np.array_equal(a.goal, b.goal)



def _assert_same_frontiers(got, expected):
    assert len(got) == len(expected)
    for a, b in zip(got, expected):
        assert np.array_equal(a.cells, b.cells) and a.goal_cell == b.goal_cell
        assert np.array_equal(a.centre, b.centre) and np.array_equal(a.goal, b.goal)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frontier_mask_kept_cell_by_cell_gives_the_whole_maps_frontiers(seed):
    """Rooms appear, walls appear and vanish, free cells turn back: after every change the
    mask equals frontier_mask and its frontiers (clusters, order, goals) find_frontiers'."""
    from mjexplore.topology.frontiers import FrontierMask

    rng = np.random.default_rng(seed)
    data = np.full((90, 130), UNKNOWN, np.int8)
    grid = GridMap(data, 0.05)
    kept = FrontierMask(grid.shape)
    kept.reset(grid)
    for step in range(25):
        before = data.copy()
        r, c = rng.integers(0, 85), rng.integers(0, 125)
        data[r:r + rng.integers(2, 25), c:c + rng.integers(2, 35)] = \
            (FREE, OCCUPIED, UNKNOWN)[rng.choice(3, p=[0.7, 0.2, 0.1])]
        data[rng.random(data.shape) < 0.002] = OCCUPIED
        if step == 0:
            data[0:4, 20:60] = FREE  # Free space on the map's edge.
        changed = np.flatnonzero(data != before)
        kept.update(grid, changed)
        assert np.array_equal(kept.mask.astype(bool), frontier_mask(grid))
        assert np.array_equal(np.sort(kept._listed[:kept._n]), np.flatnonzero(kept.mask))
        rows, cols = np.nonzero(grid.known)
        r0, r1, c0, c1 = kept.box
        assert r0 <= rows.min() and r1 >= rows.max() and c0 <= cols.min() and c1 >= cols.max()
        _assert_same_frontiers(kept.frontiers(grid, 3, 0.5), find_frontiers(grid, 3, 0.5))



def _groups_one_by_one(cells, lab, min_size, max_cells):
    """The frontier cell groups as a loop over the clusters cut them (the reference for
    the vectorised cut): runs along each long cluster's longer axis."""
    groups = []
    for label in np.unique(lab):
        group = cells[lab == label]
        if len(group) < min_size:
            continue
        extent = np.ptp(group, axis=0)
        if extent.max() + 1 <= max_cells:
            groups.append(group)
            continue
        axis = int(np.argmax(extent))
        order = np.argsort(group[:, axis], kind="stable")
        pieces = int(np.ceil((extent[axis] + 1) / max_cells))
        groups.extend(group[idx] for idx in np.array_split(order, pieces))
    return groups


@pytest.mark.parametrize("seed,max_length", [(0, 0.3), (1, 0.5), (2, 1.0), (3, 2.0)])
def test_long_clusters_are_cut_as_a_loop_over_them_cuts_them(seed, max_length):
    import cv2

    grid = _random_partial_map(seed, True)
    mask = frontier_mask(grid)
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    cells = np.argwhere(mask)
    expected = _groups_one_by_one(cells, labels[mask], 3, max_length / grid.resolution)
    got = find_frontiers(grid, 3, max_length)
    assert len(got) == len(expected) > 10
    if max_length <= 1.0:  # Some clusters were cut.
        assert len(got) > (np.bincount(labels[mask])[1:] >= 3).sum()
    for f, group in zip(got, expected):
        assert np.array_equal(f.cells, group)


def test_tracker_frontiers_of_an_episode_are_the_whole_maps():
    """Along a real episode (office, physics, nearest frontier), every decision's
    frontiers read from the tracker's box of known cells are those of the whole map."""
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.topology.pipeline import TopologyTracker

    episode = Episode(resolve_scene("office"), make_explorer("nearest"), 0,
                      EpisodeConfig(max_time=90.0))
    tracker = episode.tracker
    checked = []

    def frontiers(grid, free=None):
        got = TopologyTracker.frontiers(tracker, grid, free)
        cfg = tracker.config
        _assert_same_frontiers(got, find_frontiers(grid, cfg.frontier_min_size,
                                                   cfg.frontier_max_length))
        box = tracker._frontier_mask.box
        checked.append((len(got), (box[1] - box[0] + 1) * (box[3] - box[2] + 1)))
        return got

    tracker.frontiers = frontiers
    episode.run()
    assert len(checked) >= 10 and sum(n for n, _ in checked) > 50
    assert min(area for _, area in checked) < episode.mapper.state.size / 4  # Not the map.


def test_frontier_distances_read_at_the_windows_equal_the_whole_maps():
    from mjexplore.episode.explorer import ExplorationState
    from mjexplore.navigation.planner import Costmap, PlannerConfig
    from mjexplore.topology.gvd import DynamicGVD

    grid = _random_partial_map(5, True)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    costmap = Costmap(grid, gvd.distance2, PlannerConfig())
    costmap.update(None)
    fronts = find_frontiers(grid)
    state = ExplorationState(grid=grid, pose=np.array([0.5, 0.5, 0.0]), time=0.0,
                             frontiers=fronts, costmap=costmap, visited=np.zeros((0, 2)))
    k = 10  # 0.5 m at 0.05 m.
    for stop in (0, 1):
        mask = np.zeros(grid.shape, bool)
        for f in fronts:
            r, c = f.goal_cell
            mask[max(r - k, 0):r + k + 1, max(c - k, 0):c + k + 1] = True
        whole = costmap.distances_from(state.pose[:2], mask, stop)
        reference = [whole[max(f.goal_cell[0] - k, 0):f.goal_cell[0] + k + 1,
                           max(f.goal_cell[1] - k, 0):f.goal_cell[1] + k + 1].min()
                     for f in fronts]
        got = state.frontier_distances(nearest_only=bool(stop))
        assert np.array_equal(got, reference) and np.isfinite(got).any()
        assert not costmap._windows.any()  # Cleared for the next call.
