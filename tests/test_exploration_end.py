"""When exploration is over: given-up goals, their forgetting, and a true ``no_frontiers``."""

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.navigation.blacklist import BlacklistConfig, GoalBlacklist
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.importer import scene_from_grid
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig

RES = 0.05


def _two_rooms(tmp_path, gap_to_the_east: bool):
    """20 x 7 m: a south corridor and a north room split by a wall at y = 3.5 m with a 0.1 m
    slit at x = 1.5 m (the lidar sees through it, the robot does not pass), and, if
    ``gap_to_the_east``, a 3 m opening at its east end."""
    data = np.full((140, 400), FREE, np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = OCCUPIED
    data[69:72, :340 if gap_to_the_east else 400] = OCCUPIED
    data[69:72, 30:32] = FREE  # The slit.
    scene = scene_from_grid(GridMap(data, RES), "rooms", {"source": "test"},
                            start=(1.55, 2.0, np.pi / 2))
    return load_scene_files(write_scene(scene, tmp_path / "rooms"))


def _config(**kwargs) -> EpisodeConfig:
    return EpisodeConfig(**{"sim": SimConfig(dynamics="kinematic"), "start_jitter": (0.0, 0.0),
                            **kwargs})


def _preload(episode: Episode, known: np.ndarray) -> None:
    """Marks the ground truth's ``known`` cells as mapped, as if seen earlier."""
    mapper, gt = episode.mapper, episode.scene.ground_truth
    known = known & (mapper.state != gt.data)
    cfg = mapper.config
    mapper.logodds[known] = np.where(gt.data[known] == OCCUPIED, cfg.log_odds_max,
                                     cfg.log_odds_min)
    mapper.state[known] = np.where(gt.data[known] == OCCUPIED, OCCUPIED, FREE)
    changed = np.argwhere(known)
    episode.tracker.observe(mapper.grid, changed)
    episode.agent._costmap.update(np.concatenate([changed[:, 0] * gt.shape[1] + changed[:, 1],
                                            episode.tracker.gvd.last_changed]))
    episode.counter.update(mapper.state, changed, gt.shape[1])


def test_a_frontier_behind_a_detour_is_reached_not_given_up(tmp_path):
    # All is known but a pocket in the north room behind the slit: the only path there runs
    # 17 m east, round the wall's end, and 17 m back west. In straight line the robot gets
    # farther for ~35 s, which the old straight-line progress rule gave up after 20 s.
    episode = Episode(_two_rooms(tmp_path, gap_to_the_east=True), NearestFrontier(), 0,
                      _config(max_time=200.0))
    known = np.ones(episode.mapper.state.shape, bool)
    known[90:138, 60:160] = False  # x 3-8 m, y 4.5-6.9 m: out of the slit's view.
    _preload(episode, known)
    result = episode.run()
    assert result.goals[0, 1] < 8.5 and result.goals[0, 2] > 4.4  # The pocket...
    assert result.metrics["end_reason"] == "explored"  # ...got seen...
    assert result.metrics["given_up"]["no_progress"] == 0  # ...and was never given up.


def test_a_route_that_flips_between_two_ways_round_does_not_hold_the_goal(tmp_path):
    # The replanned path to the goal flips between 3 m and 6 m every 2 s (two ways round an
    # obstacle the map keeps changing its mind about): each flip to the longer one may
    # restart the progress clock only so often, then the goal is given up.
    # The goal: the pocket of the detour test, 34 m away by the only path (about 70 s).
    episode = Episode(_two_rooms(tmp_path, gap_to_the_east=True), NearestFrontier(), 0,
                      _config(max_time=400.0))
    known = np.ones(episode.mapper.state.shape, bool)
    known[90:138, 60:160] = False
    _preload(episode, known)
    assert episode.step() and episode.goal is not None
    goal = episode.goal.copy()
    episode.navigator.remaining_length = lambda pose: 3.0 if episode.sim.time % 4 < 2 else 6.0
    while episode.step() and episode.sim.time < 300.0:
        if not np.array_equal(episode.goal, goal):
            break
    assert episode.blacklist.reasons()["no_progress"] == 1
    budget = (episode.config.longer_route_restarts + 1) * 4.0 + episode.config.progress_timeout
    assert episode.sim.time < budget + 5.0


def test_no_frontiers_fires_only_when_none_is_reachable(tmp_path):
    # Without the east opening the north room is seen through the slit only: its frontiers
    # cannot be reached, and the episode must end as no_frontiers (not at the time cap).
    result = Episode(_two_rooms(tmp_path, gap_to_the_east=False), NearestFrontier(), 0,
                     _config(max_time=600.0)).run()
    assert result.metrics["end_reason"] == "no_frontiers"
    assert result.metrics["exploration_time_s"] < 300.0
    assert result.metrics["exploration_ratio"] < 0.9  # The north room stays unseen.


def test_the_episode_goes_on_while_a_given_up_frontier_is_reachable():
    # Every frontier goal at the start is given up (as if no progress had been made towards
    # it): with nothing else left, the episode goes to frontier cells away from those goals
    # or offers the goals again, and the loop gets explored.
    episode = Episode(resolve_scene("train_loop"), NearestFrontier(), 0, _config())
    state = episode.decision_state()
    assert state.frontiers
    for f in state.frontiers:
        episode.blacklist.add(f.goal, "no_progress", episode.mapper.grid)
    assert not episode.decision_state().frontiers
    m = episode.run().metrics
    assert m["end_reason"] == "explored"
    assert m["fallbacks"] >= 1


def _grid() -> GridMap:
    data = np.full((100, 100), UNKNOWN, np.int8)
    data[:, :40] = FREE
    return GridMap(data, RES)


def test_a_given_up_goal_is_forgotten_when_the_map_around_it_changes():
    grid = _grid()
    blacklist = GoalBlacklist(BlacklistConfig(forget_radius=1.0, forget_area=0.25))
    goal = np.array([2.0, 2.5])  # Cell column 40: the first unknown one.
    blacklist.add(goal, "no_path", grid)
    blacklist.add(np.array([0.5, 0.5]), "no_path", grid)  # Far from the change.
    assert len(blacklist) == 2
    grid.data[40:60, 40:44] = FREE  # 80 cells = 0.2 m^2: not yet enough.
    assert blacklist.forget_changed(grid) == 0 and len(blacklist) == 2
    grid.data[40:60, 44:46] = FREE  # 120 cells = 0.3 m^2 near the goal.
    assert blacklist.forget_changed(grid) == 1
    np.testing.assert_allclose(blacklist.points(), [[0.5, 0.5]])


def test_reoffer_lifts_retryable_goals_until_their_attempts_run_out():
    grid = _grid()
    blacklist = GoalBlacklist(BlacklistConfig(max_attempts=2))
    stuck, seen = np.array([1.0, 1.0]), np.array([3.0, 3.0])
    blacklist.add(stuck, "no_progress", grid)
    blacklist.add(seen, "seen_open", grid)
    assert blacklist.reoffer() == 1  # The robot stood at `seen`: no reason to go back.
    np.testing.assert_allclose(blacklist.points(), [seen])
    blacklist.add(stuck + 0.1, "no_progress", grid)  # Failed again, same place, same map.
    assert blacklist.reoffer() == 0 and len(blacklist) == 2


@pytest.mark.parametrize("reason", ["nonsense", ""])
def test_unknown_reason_is_refused(reason):
    with pytest.raises(ValueError, match="reason"):
        GoalBlacklist().add(np.zeros(2), reason, _grid())


def test_the_robot_acts_on_its_estimate_and_the_metrics_say_how_far_off_it_was():
    scene = resolve_scene("train_loop")
    config = _config(localization="odometry", max_time=30.0,
                     sim=SimConfig(dynamics="kinematic", odometry_error="typical"))
    episode = Episode(scene, NearestFrontier(), 3, config)
    m = episode.run().metrics
    drift = np.hypot(*(episode.pose[:2] - episode.sim.pose[:2]))
    assert drift > 0.005  # The estimate has drifted from the truth...
    np.testing.assert_allclose(episode.visited[-1], episode.pose[:2], atol=0.3)  # ...and is
    # what the robot used; the metrics report the error.
    assert m["localization"] == "odometry"
    assert 0 < m["pose_error_rmse_m"] <= m["pose_error_max_m"]
    assert m["pose_error_aligned_rmse_m"] <= m["pose_error_rmse_m"]
    truth = Episode(scene, NearestFrontier(), 3, _config(max_time=30.0)).run().metrics
    assert truth["pose_error_max_m"] == truth["pose_error_aligned_rmse_m"] == 0.0


def test_an_estimate_off_the_map_ends_the_episode_as_lost(tmp_path):
    config = _config(localization="odometry", max_time=60.0)
    episode = Episode(_two_rooms(tmp_path, gap_to_the_east=True), NearestFrontier(), 0, config)
    for _ in range(20):
        episode.step()
    episode.localizer.reset((-5.0, -5.0, 0.0), odom_pose=episode.sim.odom_pose)  # Off the map.
    episode.agent.goal = None  # A decision is due now.
    m = episode.run().metrics
    assert m["end_reason"] == "lost"
    # With the true pose the same start explores on.
    truth = Episode(_two_rooms(tmp_path, gap_to_the_east=True), NearestFrontier(), 0,
                    _config(max_time=20.0)).run().metrics
    assert truth["end_reason"] == "time_limit"


def test_unknown_localization_is_refused():
    from mjexplore.errors import UserInputError

    with pytest.raises(UserInputError, match="scan_matching"):
        EpisodeConfig(localization="gps")
