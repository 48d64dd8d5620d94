import json
import math
from collections import defaultdict

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.eval.run import Observers
from mjexplore.explorers import make_explorer
from mjexplore.scenes.canonical import resolve_scene

pytest.importorskip("mcap_ros2")
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402

SCENE = "train_loop"


class _Scans:
    """Observer that keeps each scan's stamp and ranges."""

    def __init__(self):
        self.scans = []

    def on_scan(self, episode, scan):
        self.scans.append((scan.stamp, scan.ranges.copy()))

    def on_decision(self, episode, state):
        pass

    def on_step(self, episode):
        pass

    def close(self):
        pass


def _read(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        schemas = {c.topic: (summary.schemas[c.schema_id].name,
                             summary.schemas[c.schema_id].encoding, c.message_encoding)
                   for c in summary.channels.values()}
        messages = defaultdict(list)
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages[channel.topic].append((message.log_time, decoded))
    return header, schemas, messages


def _ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_ros2_mcap_decodes_with_the_episode_scans_map_and_simulated_stamps(tmp_path):
    from mjexplore.io.ros2_mcap import TOPICS, Ros2EpisodeLog

    path = tmp_path / "ep.mcap"
    scans = _Scans()
    log = Ros2EpisodeLog(path)
    episode = Episode(resolve_scene(SCENE), make_explorer("nearest"), 0,
                      EpisodeConfig(max_time=3.05), observer=Observers(log, scans))
    try:
        result = episode.run()
    finally:
        log.close()
    header, schemas, messages = _read(path)

    assert header.profile == "ros2"
    assert {t: s[0] for t, s in schemas.items()} == TOPICS
    assert {(s[1], s[2]) for s in schemas.values()} == {("ros2msg", "cdr")}
    assert schemas["/scan"][0] == "sensor_msgs/msg/LaserScan"
    assert schemas["/map"][0] == "nav_msgs/msg/OccupancyGrid"

    # /scan: the episode's scans, stamped with their simulated times.
    got = messages["/scan"]
    lidar = episode.sim.lidar.config
    assert len(got) == len(scans.scans) == len(result.ratio_curve) > 20
    for (log_time, msg), (stamp, ranges) in zip(got, scans.scans):
        assert _ns(msg.header.stamp) == log_time == round(stamp * 1e9)
        assert msg.header.frame_id == "base_scan"
        np.testing.assert_array_equal(np.array(msg.ranges, np.float32), ranges)
        assert msg.range_max == pytest.approx(lidar.range_max)
        assert msg.range_min == pytest.approx(lidar.range_min)
    first = got[0][1]
    assert first.angle_min == 0.0
    assert first.angle_increment == pytest.approx(2 * math.pi / len(first.ranges))

    # /map: the final map, with its geometry; every stamp is the log time.
    grid = result.grid
    log_time, occupancy = messages["/map"][-1]
    assert log_time == round(scans.scans[-1][0] * 1e9) > 3e9  # The final map, after 3 s.
    info = occupancy.info
    assert (info.width, info.height) == (grid.shape[1], grid.shape[0])
    assert info.resolution == pytest.approx(grid.resolution)
    assert (info.origin.position.x, info.origin.position.y) == pytest.approx(grid.origin[:2])
    assert occupancy.header.frame_id == "map"
    np.testing.assert_array_equal(np.array(occupancy.data, np.int8), grid.data.reshape(-1))
    assert len(messages["/map"]) == 5  # 0, 1, 2, 3 s and the end.
    for topic in ("/map", "/pose", "/odom", "/goal", "/kinematics/velocity"):
        for log_time, msg in messages[topic]:
            assert _ns(msg.header.stamp) == log_time

    # Frames (REP-105): map->odom->base_link chains to the ground-truth pose.
    static = messages["/tf_static"]
    assert len(static) == 1
    (link,) = static[0][1].transforms
    assert (link.header.frame_id, link.child_frame_id) == ("base_link", "base_scan")
    pose = {t: m.pose for t, m in messages["/pose"]}
    for log_time, tf in messages["/tf"]:
        (map_odom, odom_base) = tf.transforms
        assert (map_odom.header.frame_id, map_odom.child_frame_id) == ("map", "odom")
        assert (odom_base.header.frame_id, odom_base.child_frame_id) == ("odom", "base_link")
        a, b = map_odom.transform, odom_base.transform
        yaw = 2 * math.atan2(a.rotation.z, a.rotation.w)
        x = a.translation.x + math.cos(yaw) * b.translation.x - math.sin(yaw) * b.translation.y
        y = a.translation.y + math.sin(yaw) * b.translation.x + math.cos(yaw) * b.translation.y
        p = pose[log_time].position
        assert (x, y) == pytest.approx((p.x, p.y), abs=1e-6)

    # Goals and TER per decision; kinematics per sample.
    assert len(messages["/goal"]) == len(messages["/ter"]) == result.metrics["decisions"] >= 1
    nodes, _ = messages["/ter"][-1][1].markers
    assert nodes.ns == "ter" and len(nodes.points) == len(nodes.colors) > 0
    velocity = messages["/kinematics/velocity"]
    assert len(velocity) == len(messages["/kinematics/acceleration"]) == len(
        result.kinematics.t) - 1
    np.testing.assert_allclose([m.twist.linear.x for _, m in velocity],
                               result.kinematics.linear_velocity[1:], atol=1e-9)
    odom = messages["/odom"][-1][1]
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")


def test_explore_writes_the_ros2_profile(tmp_path, capsys):
    from mjexplore.cli import main

    out = tmp_path / "run"
    assert main(["explore", "--scene", SCENE, "--max-time", "1", "--out", str(out),
                 "--mcap-profile", "ros2", "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out)["end_reason"] == "time_limit"
    header, schemas, messages = _read(out / "episode.mcap")
    assert header.profile == "ros2"
    assert schemas["/scan"][0] == "sensor_msgs/msg/LaserScan"
    assert len(messages["/scan"]) == 11  # 10 Hz for 1 s, from 0 s.
    from mjexplore.errors import UserInputError
    from mjexplore.render.replay import RecordedEpisode

    with pytest.raises(UserInputError, match="ROS 2 messages"):
        RecordedEpisode(out / "episode.mcap")  # render reads Foxglove MCAPs only.
    assert main(["explore", "--out", str(tmp_path / "x"), "--no-mcap",
                 "--mcap-profile", "ros2"]) == 2
    assert "--mcap-profile" in capsys.readouterr().err
