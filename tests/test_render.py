"""Offscreen rendering, the 2D map panel, videos and replays."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.eval.run import write_run
from mjexplore.explorers import make_explorer
from mjexplore.maps import GridMap
from mjexplore.render import gl
from mjexplore.render.panel import FREE, OCCUPIED, UNKNOWN, PanelContent, PanelLayout, render_panel
from mjexplore.render.recorder import EpisodeVideo, VideoConfig
from mjexplore.render.scene_view import SceneView
from mjexplore.scenes.canonical import resolve_scene


def _gl_or_skip() -> None:
    try:
        gl.check_rendering()
    except UserInputError as exc:
        pytest.skip(f"no offscreen GL backend loads here: {exc}")


def _read_video(path):
    import imageio.v2 as imageio

    reader = imageio.get_reader(path)
    meta = reader.get_meta_data()
    frames = [f for f in reader]
    reader.close()
    return frames, meta


def test_panel_matches_map_occupancy_at_sampled_pixels():
    rng = np.random.default_rng(0)
    data = np.full((60, 90), -1, np.int8)
    data[5:50, 10:80] = 0
    data[20:25, 10:60] = 100
    data[rng.random(data.shape) < 0.05] = 100
    grid = GridMap(data, 0.05, (-1.0, 2.0, 0.0))
    img = render_panel(PanelContent(grid=grid), 640, 480)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    layout = PanelLayout(grid, 640, 480)
    assert layout.scale > 5  # Cells are several pixels wide: centres are unambiguous.
    cells = np.column_stack([rng.integers(0, 60, 300), rng.integers(0, 90, 300)])
    px = layout.cells_to_pixels(cells)
    expected = {-1: UNKNOWN, 0: FREE, 100: OCCUPIED}
    for (r, c), (x, y) in zip(cells, px):
        assert tuple(img[y, x]) == expected[int(data[r, c])], (r, c)
    # World points land on their cells: the cell centre of (r, c) maps to the same pixel.
    xy = np.array([[-1.0 + (12 + 0.5) * 0.05, 2.0 + (7 + 0.5) * 0.05]])
    assert np.abs(layout.to_pixels(xy)[0] - layout.cells_to_pixels([[7, 12]])[0]).max() <= 1


def test_scene_view_frames_have_the_size_and_are_not_blank():
    _gl_or_skip()
    scene = resolve_scene("train_loop")
    model = mujoco.MjModel.from_xml_path(str(scene.xml))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    view = SceneView(model, 320, 240)
    x, y, yaw = scene.start
    img = view.render(data, np.array([x, y, yaw]), np.array([[x, y], [x + 1, y]]))
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    assert img.std() > 10  # Walls, floor and trajectory, not a blank frame.
    img2 = view.render(data, np.array([x, y, yaw]))
    assert not np.array_equal(img, img2)  # The trajectory is drawn.


def test_episode_video_reads_back_with_expected_frames_and_duration(tmp_path):
    _gl_or_skip()
    config = VideoConfig(width=160, height=120, fps=10.0, sim_seconds_per_frame=0.5)
    path = tmp_path / "ep.mp4"
    film = EpisodeVideo(path, config, "test")
    episode = Episode(resolve_scene("train_loop"), make_explorer("nearest"), 0,
                      EpisodeConfig(max_time=6.0), observer=film)
    try:
        episode.run()
    finally:
        film.close()
    frames, meta = _read_video(path)
    # One frame every 0.5 s of the 6 s episode (t = 0 .. 5.5 s), plus the final frame.
    assert film.writer.frames == len(frames) == 13
    assert frames[0].shape == (120, 320, 3)
    assert meta["fps"] == 10.0
    assert meta["duration"] == pytest.approx(len(frames) / 10.0, abs=0.11)
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1  # It moves.


def test_video_file_is_closed_on_an_exception(tmp_path):
    from mjexplore.io.video import VideoWriter

    path = tmp_path / "v.mp4"
    with pytest.raises(KeyboardInterrupt):
        with VideoWriter(path, 5.0) as writer:
            for i in range(7):
                writer.append(np.full((32, 48, 3), i * 30, np.uint8))
            raise KeyboardInterrupt
    frames, _ = _read_video(path)
    assert len(frames) == 7
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_video_path_that_is_a_folder_is_refused_up_front(tmp_path):
    from mjexplore.io.video import VideoWriter

    with pytest.raises(UserInputError, match="is a folder"):
        VideoWriter(tmp_path, 5.0)
    assert list(tmp_path.iterdir()) == []


def test_explore_video_stills_and_replay(tmp_path):
    _gl_or_skip()
    from mjexplore.render.replay import render_run

    config = VideoConfig(width=160, height=120, fps=10.0, sim_seconds_per_frame=1.0)
    out = tmp_path / "run"
    metrics = write_run(out, resolve_scene("train_loop"), "nearest", 0,
                        EpisodeConfig(max_time=8.0), video=config)
    assert metrics["exploration_time_s"] == pytest.approx(8.0)
    for name in ("video.mp4", "ter.png", "scene.png", "episode.mcap"):
        assert (out / name).is_file(), name
    frames, _ = _read_video(out / "video.mp4")
    assert len(frames) == 9  # t = 0 .. 7 s, plus the final frame.
    summary = render_run(out, tmp_path / "replay.mp4", config)
    replay, _ = _read_video(tmp_path / "replay.mp4")
    # Poses are logged at every scan up to t = 8 s: frames at t = 0, 1, ..., 8 s.
    assert summary["frames"] == len(replay) == 9
    assert replay[0].shape == (120, 320, 3)
    with pytest.raises(UserInputError, match="not a run folder"):
        render_run(tmp_path, None, config)


@pytest.mark.parametrize("period, max_time, expected", [
    (0.05, 2.0, 41),  # t = 0, 0.05, ..., 2.0: finer than the 0.1 s scans.
    (1.0, 7.3, 9),  # t = 0, 1, ..., 7 and the final state at 7.3 s.
])
def test_live_and_replayed_videos_have_one_frame_per_period_and_the_final_state(
        tmp_path, period, max_time, expected):
    _gl_or_skip()
    from mjexplore.render.replay import render_run

    config = VideoConfig(width=64, height=48, fps=10.0, sim_seconds_per_frame=period)
    out = tmp_path / "run"
    write_run(out, resolve_scene("train_loop"), "nearest", 0, EpisodeConfig(max_time=max_time),
              video=config)
    live, meta = _read_video(out / "video.mp4")
    assert len(live) == expected
    assert meta["duration"] == pytest.approx(expected / 10.0, abs=0.11)  # Time scale kept.
    assert render_run(out, tmp_path / "replay.mp4", config)["frames"] == expected
    mode = lambda name: oct((out / name).stat().st_mode & 0o777)  # noqa: E731
    assert mode("video.mp4") == mode("metrics.json")  # The umask's, not a temp file's 0600.


def test_rendering_failure_names_the_packages(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("no display")

    monkeypatch.setattr(gl.mujoco, "Renderer", broken)
    monkeypatch.setattr("mjexplore.MUJOCO_IMPORTED_FIRST", False)
    with pytest.raises(UserInputError, match="libegl1 libegl-mesa0 libgl1-mesa-dri"):
        gl.check_rendering()


def test_cli_rejects_odd_video_size(tmp_path):
    from mjexplore.cli import main

    rc = main(["explore", "--scene", "train_loop", "--out", str(tmp_path / "r"), "--video",
               str(tmp_path / "v.mp4"), "--video-size", "641x480"])
    assert rc == 2 and not (tmp_path / "r").exists()




def test_a_team_panel_draws_every_robot_in_its_colour():
    from mjexplore.render.panel import ROBOT, TEAMMATE_COLOURS
    from mjexplore.render.recorder import episode_panel

    episode = Episode(resolve_scene("train_loop"), [make_explorer("nearest") for _ in range(3)],
                      0, EpisodeConfig(max_time=3.0))
    episode.run()
    img = episode_panel(episode, 640, 480)
    for colour in (ROBOT, TEAMMATE_COLOURS[0], TEAMMATE_COLOURS[1]):
        assert (img == colour).all(axis=-1).sum() > 20, colour
    alone = episode_panel(Episode(resolve_scene("train_loop"), make_explorer("nearest"), 0,
                                  EpisodeConfig(max_time=3.0)), 640, 480)
    assert (alone == TEAMMATE_COLOURS[0]).all(axis=-1).sum() == 0


def test_explore_films_a_team_that_localises_itself(tmp_path):
    """The issue's command, short: two robots, each with scan matching on odometry with
    errors, filmed."""
    _gl_or_skip()
    import json

    from mjexplore.cli import main

    out, film = tmp_path / "team", tmp_path / "team.mp4"
    assert main(["explore", "--scene", "train_loop", "--robots", "2", "--explorer", "nearest",
                 "--localization", "scan_matching", "--odometry-error", "typical",
                 "--video", str(film), "--video-size", "160x120", "--max-time", "6",
                 "--no-progress", "--out", str(out)]) == 0
    frames, _ = _read_video(film)
    assert len(frames) == 7 and frames[0].shape == (120, 320, 3)  # t = 0 .. 5 s, the end.
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["robots"] == 2 and metrics["localization"] == "scan_matching"
    assert all(r["pose_error_rmse_m"] < 0.3 for r in metrics["per_robot"])
    for name in ("robot_0/kinematics.csv", "robot_1/coverage.csv", "ter.png", "scene.png",
                 "episode.mcap", "video.mp4"):
        assert (out / name).is_file(), name
