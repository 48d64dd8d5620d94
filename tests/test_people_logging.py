"""Pedestrians in the episode's records (issue 51): the MCAP's /people topic (Foxglove
scene entities, ROS 2 markers) where the crowd is, no such topic without people, and the
people drawn in the video's map panel and 3D view."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from mcap.reader import make_reader

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.eval.run import Observers
from mjexplore.explorers import make_explorer
from mjexplore.io.mcap_log import PEOPLE_TOPIC, TOPICS, FoxgloveEpisodeLog
from mjexplore.io.stamps import sim_ns
from mjexplore.maps import FREE, GridMap
from mjexplore.render.panel import FREE as FREE_RGB
from mjexplore.render.panel import PERSON, PanelContent, PanelLayout, render_panel
from mjexplore.render.recorder import episode_panel
from mjexplore.render.replay import _decoders
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.people import PeopleConfig
from mjexplore.sim.simulator import SimConfig

SCENE = "train_loop"
SECONDS = 3.0


def _config(people: int) -> EpisodeConfig:
    return EpisodeConfig(max_time=SECONDS, sim=SimConfig(
        dynamics="kinematic", people=PeopleConfig(count=people) if people else None))


class _Crowd:
    """Observer that keeps where the crowd is at each simulated time it is shown (ns)."""

    def __init__(self):
        self.at: dict[int, np.ndarray] = {}

    def _note(self, world):
        self.at[sim_ns(world.time)] = world.crowd.positions.copy()

    def on_scan(self, agent, scan):
        self._note(agent.episode.world)

    def on_step(self, episode):
        self._note(episode.world)

    def close(self):
        pass


def _run(path, people: int, profile: str = "foxglove") -> tuple[Episode, _Crowd | None]:
    if profile == "ros2":
        from mjexplore.io.ros2_mcap import Ros2EpisodeLog

        log: object = Ros2EpisodeLog(path)
    else:
        log = FoxgloveEpisodeLog(path)
    crowd = _Crowd() if people else None
    observers = Observers(log, crowd)
    try:
        episode = Episode(resolve_scene(SCENE), make_explorer("nearest"), 0, _config(people),
                          observer=observers)
        episode.run()
    finally:
        observers.close()
    return episode, crowd


def _channels(path) -> dict[str, str]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def test_foxglove_mcap_has_the_people_where_the_crowd_is(tmp_path):
    path = tmp_path / "ep.mcap"
    episode, crowd = _run(path, 3)
    assert crowd is not None
    radius, height = episode.world.crowd.config.radius, episode.world.crowd.config.height
    assert _channels(path)[PEOPLE_TOPIC] == "foxglove.SceneUpdate"
    got = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        classes = _decoders(reader.get_summary())
        for schema, _, message in reader.iter_messages(topics=[PEOPLE_TOPIC]):
            got.append((message.log_time, classes[schema.id].FromString(message.data)))
    # 10 Hz of simulated time, from the start to the end, stamped with it.
    assert [t for t, _ in got] == [round(k * 1e8) for k in range(round(SECONDS * 10) + 1)]
    moved = False
    for log_time, update in got:
        assert len(update.entities) == 3
        expected = crowd.at[log_time]  # Where the crowd was at that simulated time.
        for i, entity in enumerate(update.entities):
            assert entity.id == f"person_{i}" and entity.frame_id == "map"
            assert entity.timestamp.seconds * 10**9 + entity.timestamp.nanos == log_time
            (cylinder,) = entity.cylinders
            p = cylinder.pose.position
            assert (p.x, p.y) == pytest.approx(tuple(expected[i]), abs=1e-9)
            assert p.z == pytest.approx(height / 2)  # Standing on the floor.
            s = cylinder.size
            assert (s.x, s.y, s.z) == pytest.approx((2 * radius, 2 * radius, height))
            assert cylinder.bottom_scale == cylinder.top_scale == 1.0  # A cylinder, no cone.
        moved |= not np.allclose(expected, crowd.at[got[0][0]])
    assert moved  # They walked: the positions are the crowd's at each time, not its start.


def test_ros2_mcap_has_the_people_as_cylinder_markers(tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap_ros2.decoder import DecoderFactory

    from mjexplore.io.ros2_mcap import CYLINDER
    from mjexplore.io.ros2_mcap import TOPICS as ROS2_TOPICS

    path = tmp_path / "ep.mcap"
    episode, crowd = _run(path, 3, "ros2")
    assert crowd is not None
    assert _channels(path) == {**ROS2_TOPICS, PEOPLE_TOPIC: "visualization_msgs/msg/MarkerArray"}
    got = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=[PEOPLE_TOPIC]):
            got[channel.topic].append((message.log_time, decoded))
    people = got[PEOPLE_TOPIC]
    assert len(people) == round(SECONDS * 10) + 1
    for log_time, array in people:
        assert [m.id for m in array.markers] == [0, 1, 2]
        for m, xy in zip(array.markers, crowd.at[log_time]):
            assert m.type == CYLINDER and m.ns == "people" and m.header.frame_id == "map"
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == log_time
            assert (m.pose.position.x, m.pose.position.y) == pytest.approx(tuple(xy), abs=1e-9)
            assert m.scale.x == pytest.approx(2 * episode.world.crowd.config.radius)


@pytest.mark.parametrize("profile", ["foxglove", "ros2"])
def test_a_run_without_people_has_no_people_channel(tmp_path, profile):
    if profile == "ros2":
        pytest.importorskip("mcap_ros2")
    path = tmp_path / "ep.mcap"
    _run(path, 0, profile)
    topics = set(_channels(path))
    assert PEOPLE_TOPIC not in topics
    if profile == "foxglove":
        assert topics == set(TOPICS)


def test_the_panel_draws_a_person_as_a_disc_at_its_position():
    data = np.full((80, 120), FREE, np.int8)
    grid = GridMap(data, 0.05, (-1.0, 2.0, 0.0))
    person = np.array([[1.2, 3.1]])
    alone = render_panel(PanelContent(grid=grid), 640, 480)
    img = render_panel(PanelContent(grid=grid, people=person, people_radius=0.25), 640, 480)
    layout = PanelLayout(grid, 640, 480)
    x, y = layout.to_pixels(person)[0]
    assert tuple(img[y, x]) == PERSON and tuple(alone[y, x]) == FREE_RGB
    # A disc of the person's radius: the changed pixels lie within it, and fill most of it.
    r = 0.25 / grid.resolution * layout.scale
    ys, xs = np.nonzero((img != alone).any(axis=-1))
    assert np.hypot(xs - x, ys - y).max() <= r + 1.5
    assert (img == PERSON).all(axis=-1).sum() > 0.7 * np.pi * (r - 1) ** 2
    # No people, or an empty crowd: the panel as without the field.
    empty = render_panel(PanelContent(grid=grid, people=np.zeros((0, 2))), 640, 480)
    assert np.array_equal(empty, alone)


def test_an_episode_panel_draws_its_people_and_none_without():
    episode = Episode(resolve_scene(SCENE), make_explorer("nearest"), 0, _config(3))
    episode.run()
    img = episode_panel(episode, 640, 480)
    layout = PanelLayout(episode.mapper.grid, 640, 480)
    for x, y in layout.to_pixels(episode.world.crowd.positions):
        assert tuple(img[y, x]) == PERSON
    alone = Episode(resolve_scene(SCENE), make_explorer("nearest"), 0, _config(0))
    alone.run()
    assert not (episode_panel(alone, 640, 480) == PERSON).all(axis=-1).any()


def test_the_3d_view_shows_the_people():
    import mujoco

    from mjexplore.render import gl
    from mjexplore.render.scene_view import CameraConfig, SceneView
    from mjexplore.scenes.people import PERSON_GROUP

    try:
        gl.check_rendering()
    except UserInputError as exc:
        pytest.skip(f"no offscreen GL backend loads here: {exc}")
    episode = Episode(resolve_scene(SCENE), make_explorer("nearest"), 0, _config(3))
    world = episode.world
    view = SceneView(world.model, 160, 120, CameraConfig(distance=4.0))
    assert view._opt.geomgroup[PERSON_GROUP]  # The people's group is drawn.
    x, y = world.crowd.positions[0]
    shown = view.render(world.data, np.array([x, y, 0.0]))
    world.data.mocap_pos[:, 2] = -100.0  # Every person out of sight, under the floor.
    mujoco.mj_kinematics(world.model, world.data)
    hidden = view.render(world.data, np.array([x, y, 0.0]))
    changed = (shown != hidden).any(axis=-1)
    assert changed[40:80, 55:105].mean() > 0.1  # A person where the camera looks.


def test_a_replay_reads_the_people_and_stands_them_in_its_model(tmp_path, monkeypatch):
    """render's recording holds the people as logged; the replay's model gets their
    bodies, and each frame's people are where the MCAP had them."""
    from mjexplore.cli import main
    from mjexplore.render import replay

    run = tmp_path / "run"
    assert main(["explore", "--scene", SCENE, "--people", "3", "--max-time", "3",
                 "--no-progress", "--out", str(run)]) == 0
    rec = replay.RecordedEpisode(run / "episode.mcap")
    assert len(rec.people) == 31 and all(len(p[1]) == 3 for p in rec.people)
    assert rec.people[0][2] == pytest.approx(0.25) and rec.people[0][3] == pytest.approx(1.7)
    drawn = []
    real = replay.render_panel

    def spy(content, *args, **kwargs):
        drawn.append(content.people)
        return real(content, *args, **kwargs)

    monkeypatch.setattr(replay, "render_panel", spy)
    replay.render_run(run, tmp_path / "replay.mp4")
    np.testing.assert_array_equal(drawn[-1], rec.people[-1][1])
    no_people = tmp_path / "alone"
    assert main(["explore", "--scene", SCENE, "--max-time", "3", "--no-progress",
                 "--out", str(no_people)]) == 0
    assert replay.RecordedEpisode(no_people / "episode.mcap").people == []
