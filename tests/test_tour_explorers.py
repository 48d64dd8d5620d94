"""The tour solver and the explorers built on it: the ground-truth oracle, explore_lite and
frontier_tsp; and the episode's check of an explorer's "nothing left"."""

import json

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.explorer import ExplorationState
from mjexplore.eval.summaries import merge_summaries
from mjexplore.explorers import make_explorer
from mjexplore.mapping.metrics import exploration_ratio, observable_ground_truth
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.navigation.tour import CoarseGraph, exhaustive_open_tour, open_tour, tour_length
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.topology.frontiers import find_frontiers
from mjexplore.topology.gvd import DynamicGVD


def state_of(grid, pose, ground_truth=None, **kw):
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    costmap = Costmap(grid, gvd.distance2, PlannerConfig())
    return ExplorationState(grid, np.asarray(pose, float), 0.0, find_frontiers(grid), costmap,
                            np.zeros((0, 2)), ground_truth=ground_truth, **kw)


def walled(rows, cols):
    data = np.full((rows, cols), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    return data


def nearest_first_length(distance):
    """Length of the order that always goes to the nearest place not yet visited."""
    here, left, total = 0, set(range(1, len(distance))), 0.0
    while left:
        nxt = min(left, key=lambda j: distance[here, j])
        total += distance[here, nxt]
        here = nxt
        left.remove(nxt)
    return total


@pytest.mark.parametrize("seed", range(6))
def test_open_tour_matches_the_exhaustive_optimum_on_small_instances(seed):
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 20, (9, 2))
    distance = np.linalg.norm(points[:, None] - points[None], axis=2)
    order = open_tour(distance)
    assert sorted(order) == list(range(1, 9))
    best = tour_length(distance, exhaustive_open_tour(distance))
    assert tour_length(distance, order) <= 1.1 * best


def test_coarse_graph_distances_follow_the_corridors():
    # A U-shaped corridor: the two arms' ends are 4 m apart in a straight line but 20 m
    # apart along the U.
    data = np.full((100, 100), OCCUPIED, np.int8)
    data[10:20, 10:90] = FREE   # Bottom.
    data[10:90, 10:20] = FREE   # Left arm.
    data[10:90, 80:90] = FREE   # Right arm.
    data[50:90, 20:80] = OCCUPIED
    grid = GridMap(data, 0.1)
    state = state_of(grid, (1.5, 8.5))
    graph = CoarseGraph(grid, state.costmap.traversable, block=2)
    d = graph.distance_matrix(np.array([[1.5, 8.5], [8.5, 8.5]]))
    straight = 7.0
    along = 7.4 + 7.0 + 7.4  # Down, across, up (centre lines of the arms).
    assert d[0, 1] > 2.5 * straight
    assert abs(d[0, 1] - along) < 0.1 * along
    assert np.isinf(graph.distance_matrix(np.array([[1.5, 8.5], [5.0, 7.0]]))[0, 1])


def test_frontier_tsp_tour_is_shorter_than_nearest_first():
    # A corridor with a small opening just behind the robot and three ahead: going to the
    # nearest frontier first leaves the one behind for a long way back.
    data = np.full((30, 240), OCCUPIED, np.int8)
    data[10:20, 1:239] = FREE
    data[10:20, 239] = UNKNOWN                  # The corridor's far end (x = 24 m).
    for x in (5.9, 9.0, 12.0):                  # Openings in the upper wall ahead...
        c = int(round(x / 0.1))
        data[20, c - 3:c + 3] = UNKNOWN
    data[9, 17:23] = UNKNOWN                    # ...and one in the lower wall behind.
    grid = GridMap(data, 0.1)
    state = state_of(grid, (4.0, 1.5))
    explorer = make_explorer("frontier_tsp")
    explorer.reset(np.random.default_rng(0))
    tour = explorer.plan(state)
    assert len(tour) == len(state.frontiers) == 5
    graph = CoarseGraph(grid, state.costmap.traversable)
    distance = graph.distance_matrix(np.vstack([state.pose[:2], tour]))
    tsp = tour_length(distance, list(range(1, len(tour) + 1)))
    assert tsp < nearest_first_length(distance) - 10.0  # About 24 m against 42 m.
    assert np.allclose(explorer.select_goal(state), tour[0])


def frontier_room():
    """A free room (4 x 3 m at 0.05 m) whose right wall has a wide gap to unknown space and
    whose left wall a narrow one; the robot stands right of centre."""
    data = walled(60, 80)
    data[20:40, -1] = UNKNOWN   # 1.0 m wide, centroid at x = 3.975 m.
    data[25:33, 0] = UNKNOWN    # 0.4 m wide, centroid at x = 0.025 m.
    return GridMap(data, 0.05)


def test_explore_lite_cost_and_goal_order_by_hand():
    grid = frontier_room()
    state = state_of(grid, (2.6, 1.5))
    lite = make_explorer("explore_lite", min_frontier_size=0.3)
    lite.reset(np.random.default_rng(0))
    found = lite.frontiers(state)
    assert [size for _, size, _ in found] == [20, 8]
    right, left = found
    # min_distance: straight line from the robot to the frontier's closest cell's centre.
    assert right[2] == pytest.approx(np.hypot(3.975 - 2.6, 0.0), abs=0.03)
    assert left[2] == pytest.approx(np.hypot(0.025 - 2.6, 1.475 - 1.5), abs=0.03)
    # cost = 3 * d * 0.05 - 1 * size * 0.05 (explore_lite's code): right -0.79, left 0.99.
    assert np.allclose(lite.select_goal(state), right[0])
    assert right[0] == pytest.approx([3.975, 1.5], abs=1e-6)
    # With the robot next to the narrow gap, distance outweighs size only without the
    # resolution factor: 3 * 0.40 - 0.4 = 0.8 < 3 * 3.55 - 1.0 = 9.65 against
    # 3 * 0.40 * 0.05 - 0.4 = -0.34 > 3 * 3.55 * 0.05 - 1.0 = -0.47.
    near_left = state_of(grid, (0.425, 1.5))
    assert np.allclose(lite.select_goal(near_left), right[0])
    plain = make_explorer("explore_lite", min_frontier_size=0.3,
                          resolution_scaled_distance=False)
    plain.reset(np.random.default_rng(0))
    assert np.allclose(plain.select_goal(near_left), left[0])
    # A blacklisted goal (within 5 cells) is skipped; with every goal out, it stops.
    near_left.blacklist = np.array([right[0] + 0.1])
    assert np.allclose(lite.select_goal(near_left), left[0])
    near_left.blacklist = np.array([right[0], left[0]])
    assert lite.select_goal(near_left) is None


def test_explore_lite_drops_small_frontiers_and_gives_up_without_progress():
    grid = frontier_room()
    lite = make_explorer("explore_lite")  # min_frontier_size 0.75 m: the 0.4 m gap is out.
    lite.reset(np.random.default_rng(0))
    state = state_of(grid, (2.6, 1.5))
    assert [size for _, size, _ in lite.frontiers(state)] == [20]
    goal = lite.select_goal(state)
    state.time = 29.0
    assert np.allclose(lite.select_goal(state), goal)  # Within the 30 s progress timeout.
    state.time = 31.0
    assert lite.select_goal(state) is None  # No progress: blacklisted, nothing else left.


def rooms_ground_truth():
    """Three 4 x 4 m rooms in a row joined by 1 m doors, at 0.1 m."""
    data = walled(42, 122)
    for c in (40, 81):
        data[:, c] = OCCUPIED
        data[19:29, c] = FREE
    return GridMap(data, 0.1)


def oracle_in_rooms(start, sensor_range):
    """The oracle at ``start`` in the three rooms, nothing mapped yet; and its state."""
    gt = rooms_ground_truth()
    unknown = GridMap(np.full(gt.shape, UNKNOWN, np.int8), gt.resolution)
    state = state_of(unknown, start, ground_truth=gt, sensor_range=sensor_range)
    oracle = make_explorer("oracle")
    oracle.reset(np.random.default_rng(0))
    return oracle, state


def test_oracle_covers_the_target_with_a_near_optimal_tour():
    oracle, state = oracle_in_rooms((5.0, 3.5), sensor_range=2.0)
    gt, unknown = state.ground_truth, state.grid
    plan = oracle.replan(state)
    assert 4 <= len(plan) <= 9  # Rooms on both sides, 2 m of lidar: several viewpoints.
    # The tour sees the target ratio of the observable ground truth...
    assert oracle.planned_coverage(state) >= state.target_ratio
    # ...which its viewpoints alone, without the first, would not.
    without_first = GridMap(unknown.data.copy(), gt.resolution)
    views = oracle.views
    for v in plan[1:]:
        cells = views.idx[views.ptr[v]:views.ptr[v + 1]]
        without_first.data.flat[cells] = gt.data.flat[cells]
    observable = observable_ground_truth(gt)
    assert exploration_ratio(without_first, observable) < state.target_ratio
    # Its order is within 10 % of the best order of the same viewpoints.
    points = np.vstack([state.pose[:2], views.points[plan]])
    distance = oracle.graph.distance_matrix(points)
    best = tour_length(distance, exhaustive_open_tour(distance))
    assert tour_length(distance, list(range(1, len(plan) + 1))) <= 1.1 * best
    # Its choice among candidate goals: the one nearest by path to the first viewpoint.
    first = views.points[plan[0]]
    candidates = np.array([[first[0] + 0.3, first[1]], [11.0, 2.0] if first[0] < 6 else
                           [1.0, 2.0]])
    assert oracle.expert_choice(state, candidates) == 0
    assert oracle.expert_choice(state, candidates, np.array([False, True])) == 1
    assert oracle.expert_choice(state, candidates, np.array([False, False])) == -1


def test_oracle_drops_viewpoints_whose_cells_were_seen():
    oracle, state = oracle_in_rooms((2.0, 2.0), sensor_range=3.0)
    gt, grid = state.ground_truth, state.grid
    first = oracle.replan(state)
    assert oracle.goal_open(grid) is None  # No viewpoint adopted yet.
    oracle.current = first[0]
    assert oracle.goal_open(grid)
    views = oracle.views
    seen = views.idx[views.ptr[first[0]]:views.ptr[first[0] + 1]]
    grid.data.flat[seen] = gt.data.flat[seen]  # Everything the first viewpoint sees got mapped.
    assert not oracle.goal_open(grid)
    second = oracle.replan(state)
    assert first[0] not in second
    assert len(second) <= len(first)


class GivesUp:
    """An explorer that never sees anything to do."""

    name = "gives_up"

    def reset(self, rng):
        del rng

    def select_goal(self, state):
        return None


def test_episode_goes_on_while_a_frontier_is_reachable():
    result = Episode(resolve_scene("train_loop"), GivesUp(), 0, EpisodeConfig()).run()
    m = result.metrics
    assert m["end_reason"] == "explored"
    assert m["fallbacks"] >= m["decisions"] > 0


def test_merged_summary_keeps_the_other_methods_runs():
    def run(method, seed, et, scene="maze"):
        return {"scene": scene, "method": method, "seed": seed,
                "metrics": {"exploration_time_s": et}, "ratio": {}}

    old = {"command": "bench A", "run_revisions": ["a"], "episode": {"max_time": 1800},
           "policies": {"gvn": {"sha256": "x"}}, "runs": [run("gvn", 0, 1.0),
                                                          run("nearest", 0, 2.0)]}
    new = {"command": "bench B", "run_revisions": ["b"], "episode": {"max_time": 1800},
           "policies": {}, "runs": [run("nearest", 0, 3.0), run("oracle", 0, 4.0)]}
    merged = merge_summaries(new, old)
    assert sorted((r["method"], r["metrics"]["exploration_time_s"]) for r in merged["runs"]) == \
        [("gvn", 1.0), ("nearest", 3.0), ("oracle", 4.0)]
    assert merged["run_revisions"] == ["a", "b"]
    assert merged["command"] == "bench A\nbench B"
    assert merged["policies"] == {"gvn": {"sha256": "x"}}
    # A sweep of one more scene keeps the methods' runs on the others.
    office = dict(new, runs=[run("nearest", 0, 5.0, "office")])
    assert sorted((r["scene"], r["method"]) for r in merge_summaries(office, merged)["runs"]) \
        == [("maze", "gvn"), ("maze", "nearest"), ("maze", "oracle"), ("office", "nearest")]
    other = json.loads(json.dumps(new))
    other["episode"] = {"max_time": 900}
    with pytest.raises(Exception, match="max_time"):
        merge_summaries(other, old)


def test_explore_lite_pair_of_goals_trading_places_runs_out_of_time():
    lite = make_explorer("explore_lite")
    lite.reset(np.random.default_rng(0))
    a, b = np.array([1.0, 1.0]), np.array([2.2, 1.0])
    stalled = []
    for k in range(14):  # Re-planned every 3 s, the two goals alternate, neither gets closer.
        goal, distance = (a, 5.0) if k % 2 == 0 else (b, 6.0)
        stalled.append(lite._stalled_for(goal, distance, 3.0 * k, 0.05))
    assert stalled[:2] == [0.0, 0.0]
    assert stalled[-2] > lite.progress_timeout  # a, first chosen at 0 s, stalled 36 s.
    # A goal chosen again after a long pause starts afresh; progress restarts the clock.
    assert lite._stalled_for(np.array([9.0, 9.0]), 4.0, 100.0, 0.05) == 0.0
    assert lite._stalled_for(a, 4.0, 110.0, 0.05) == 0.0
    assert lite._stalled_for(a, 3.0, 120.0, 0.05) == 0.0
    assert lite._stalled_for(a, 3.0, 125.0, 0.05) == 5.0
