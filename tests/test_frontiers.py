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
