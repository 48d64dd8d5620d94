import math

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig, episode_metrics, first_time_at, pose_errors
from mjexplore.episode.explorer import ExplorationState
from mjexplore.explorers import make_explorer
from mjexplore.navigation.navigator import NavigatorConfig
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.kinematics import KinematicsLog

SMALL_LOOP = "train_loop"


def explore(explorer, seed=0, **config):
    scene = resolve_scene(SMALL_LOOP)
    return Episode(scene, make_explorer(explorer), seed, EpisodeConfig(**config)).run()


@pytest.mark.parametrize("explorer", ["nearest", "rrt", "potential", "oracle", "explore_lite",
                                      "frontier_tsp"])
def test_explorers_fully_explore_the_small_loop(explorer):
    result = explore(explorer)
    m = result.metrics
    assert m["end_reason"] == "explored"
    assert m["exploration_ratio"] >= 0.985
    assert m["exploration_ratio"] == pytest.approx(m["exploration_ratio_check"], abs=1e-9)
    assert m["collisions"] == 0
    assert m["t80_s"] <= m["t985_s"] == m["exploration_time_s"]
    assert m["iou"] > 0.85


def test_oracle_path_is_not_longer_than_nearest():
    for seed in (0, 1):
        oracle = explore("oracle", seed).metrics["path_length_m"]
        nearest = explore("nearest", seed).metrics["path_length_m"]
        assert oracle <= nearest


def test_same_seed_same_metrics():
    a = explore("potential", seed=3).metrics
    b = explore("potential", seed=3).metrics
    assert a == b
    c = explore("potential", seed=4).metrics
    assert c != a  # The seed moves the start and the sensor noise.


def test_metrics_on_a_scripted_trajectory():
    t = np.arange(0, 10.01, 0.5)
    ratio = np.clip(t / 10.0, 0, 1) ** 0.5  # 0.8 at t = 6.4, 0.985 at t = 9.70...
    curve = np.column_stack([t, ratio])
    assert first_time_at(curve, 0.8) == pytest.approx(6.5)  # First sample at or above.
    assert first_time_at(curve, 0.985) == pytest.approx(10.0)
    assert first_time_at(curve, 1.01) is None
    # A square of side 2 m driven along x then y, sampled every 0.1 s at 1 m/s.
    s = np.arange(0, 4.01, 0.1)
    x = np.minimum(s, 2.0)
    y = np.maximum(s - 2.0, 0.0)
    pose = np.column_stack([x, y, np.zeros_like(s)])
    log = KinematicsLog(t=s, linear_velocity=np.ones_like(s), angular_velocity=np.zeros_like(s),
                        linear_acceleration=np.zeros_like(s),
                        angular_acceleration=np.zeros_like(s), cmd_linear=np.ones_like(s),
                        cmd_angular=np.zeros_like(s), pose=pose, odom_pose=pose)
    m = episode_metrics(curve, log, final_iou=0.9, collisions=2, end_reason="explored")
    assert m["path_length_m"] == pytest.approx(4.0)
    assert m["exploration_time_s"] == pytest.approx(10.0)
    assert m["exploration_ratio"] == pytest.approx(1.0)
    assert m["t80_s"] == pytest.approx(6.5) and m["t985_s"] == pytest.approx(10.0)
    assert m["collisions"] == 2 and m["mean_speed_mps"] == pytest.approx(0.4)


def test_aligned_pose_error_sets_the_frame_aside_and_keeps_the_distortion():
    rng = np.random.default_rng(0)
    truth = np.cumsum(rng.normal(size=(200, 2)), axis=0)
    # The same trajectory in a frame turned by 2 degrees and shifted: a large error as is,
    # none once aligned.
    a = np.radians(2.0)
    turned = truth @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + (0.3, -0.2)
    m = pose_errors(turned, truth)
    assert m["pose_error_rmse_m"] > 0.3 and m["pose_error_aligned_rmse_m"] < 1e-6
    # A distortion (a 1 % scale) stays; no rotation fits it away.
    scaled = pose_errors(truth * 1.01, truth)
    spread = np.sqrt(((truth - truth.mean(0)) ** 2).sum(1).mean())
    assert scaled["pose_error_aligned_rmse_m"] == pytest.approx(0.01 * spread, rel=1e-3)
    # A mirror image is not a rotation: it is not aligned away.
    assert pose_errors(truth * (1, -1), truth)["pose_error_aligned_rmse_m"] > 1.0
    assert pose_errors(np.zeros((0, 2)), np.zeros((0, 2)))["pose_error_max_m"] == 0.0


class FarGoal:
    """Always the same far, reachable goal."""

    name = "far"

    def reset(self, rng):
        self.goal = None

    def select_goal(self, state: ExplorationState):
        return np.array([state.pose[0], state.pose[1] - 3.0]) if self.goal is None else self.goal


@pytest.mark.parametrize("strikes", [0, 2])
def test_lingering_ends_the_episode_after_its_strikes(strikes):
    # The explorer insists on one goal: each lingering spell gives it up, and the episode
    # ends at the spell after the last strike.
    scene = resolve_scene(SMALL_LOOP)
    config = EpisodeConfig(navigator=NavigatorConfig(linger_radius=100.0, linger_time=5.0),
                           linger_strikes=strikes)
    episode = Episode(scene, FarGoal(), 0, config)
    result = episode.run()
    assert result.metrics["end_reason"] == "lingering"
    assert min(strikes, 1) <= result.metrics["given_up"]["lingered"] <= strikes
    assert result.metrics["exploration_time_s"] == pytest.approx(5.0 * (strikes + 1), abs=0.25)


def test_time_limit_and_unknown_explorer():
    result = explore("nearest", max_time=3.0)
    assert result.metrics["end_reason"] == "time_limit"
    from mjexplore.errors import UserInputError

    with pytest.raises(UserInputError, match="unknown explorer"):
        make_explorer("teleport")


def test_mcap_log_reads_back(tmp_path):
    from collections import Counter

    from mcap.reader import make_reader

    from mjexplore.eval.run import run_episode
    from mjexplore.io.mcap_log import TOPICS

    path = tmp_path / "ep.mcap"
    result = run_episode(resolve_scene(SMALL_LOOP), "nearest", 0, EpisodeConfig(max_time=8.0),
                         mcap_path=path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        counts = Counter()
        last = {}
        for _schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            assert message.log_time >= last.get(channel.topic, 0)  # Simulated, in order.
            last[channel.topic] = message.log_time
    assert set(topics) == set(TOPICS)
    assert topics["/scan"] == "foxglove.LaserScan" and topics["/map"] == "foxglove.Grid"
    assert topics["/tf"] == "foxglove.FrameTransforms" and topics["/ter"] == "foxglove.SceneUpdate"
    scans = len(result.ratio_curve)
    assert counts["/scan"] == counts["/tf"] == counts["/pose"] == counts["/odom"] == scans
    assert counts["/goal"] == counts["/ter"] == result.metrics["decisions"]
    assert counts["/map"] == math.ceil(8.0 / 1.0) + 1
    assert counts["/kinematics"] == len(result.kinematics.t) - 1
    assert max(last.values()) <= 8.0e9 + 1


def test_mcap_tf_puts_the_robot_where_the_map_was_built_and_ends_with_the_final_map(
        tmp_path):
    from mcap.reader import make_reader

    from mjexplore.eval.run import run_episode
    from mjexplore.render.replay import _decoders, _yaw

    path = tmp_path / "ep.mcap"
    result = run_episode(resolve_scene(SMALL_LOOP), "nearest", 0, EpisodeConfig(max_time=7.3),
                         mcap_path=path)
    tf, pose, maps = {}, {}, []
    with open(path, "rb") as f:
        reader = make_reader(f)
        classes = _decoders(reader.get_summary())
        for schema, channel, message in reader.iter_messages(topics=["/tf", "/pose", "/map"]):
            msg = classes[schema.id].FromString(message.data)
            if channel.topic == "/tf":
                tf[message.log_time] = {(t.parent_frame_id, t.child_frame_id): (
                    t.translation.x, t.translation.y, _yaw(t.rotation)) for t in msg.transforms}
            elif channel.topic == "/pose":
                p = msg.pose
                pose[message.log_time] = (p.position.x, p.position.y, _yaw(p.orientation))
            else:
                maps.append((message.log_time, np.frombuffer(msg.data, np.int8)))
    for stamp, frames in tf.items():
        (mx, my, myaw), (ox, oy, oyaw) = frames["map", "odom"], frames["odom", "base_link"]
        c, s = math.cos(myaw), math.sin(myaw)
        chained = (mx + c * ox - s * oy, my + s * ox + c * oy, myaw + oyaw)
        assert np.allclose(chained[:2], pose[stamp][:2], atol=1e-6)
        assert math.isclose(math.remainder(chained[2] - pose[stamp][2], math.tau), 0.0,
                            abs_tol=1e-6)
    assert maps[-1][0] == round(7.3e9)  # Between the 1 s ticks: logged at the end.
    assert np.array_equal(maps[-1][1], result.grid.data.reshape(-1))


@pytest.mark.parametrize("explorer", ["nearest", "potential"])
def test_explorers_choose_a_goal_on_a_map_smaller_than_their_coarse_cells(explorer):
    from mjexplore.maps import FREE, UNKNOWN, GridMap
    from mjexplore.navigation.planner import Costmap, PlannerConfig
    from mjexplore.topology.frontiers import find_frontiers

    grid = GridMap(np.array([[FREE, FREE, UNKNOWN]] * 3, np.int8), 0.05)
    costmap = Costmap(grid, np.full(grid.shape, 10**6, np.int64), PlannerConfig(
        lethal_radius=0.0, soft_radius=0.01))
    state = ExplorationState(grid, np.array([0.025, 0.075, 0.0]), 0.0,
                             find_frontiers(grid, min_size=1), costmap, np.zeros((0, 2)))
    goal = make_explorer(explorer).select_goal(state)
    assert goal is not None and np.allclose(goal, state.frontiers[0].goal)


def test_rrt_mean_shift_finds_one_mode_per_cluster():
    from mjexplore.explorers.rrt import mean_shift

    rng = np.random.default_rng(0)
    centres = np.array([[1.0, 1.0], [1.25, 1.0], [4.0, 2.0], [8.0, -3.0]])
    points = np.concatenate([c + rng.normal(0, 0.03, (40, 2)) for c in centres])
    modes = mean_shift(points, bandwidth=0.3)
    # The first two clusters lie within the bandwidth: one mode between them.
    assert len(modes) == 3
    for c in ([1.125, 1.0], [4.0, 2.0], [8.0, -3.0]):
        assert np.min(np.hypot(*(modes - c).T)) < 0.15
    # Kept modes are more than a bandwidth apart.
    gaps = np.hypot(*(modes[:, None] - modes[None]).transpose(2, 0, 1))
    assert gaps[~np.eye(len(modes), dtype=bool)].min() > 0.3
