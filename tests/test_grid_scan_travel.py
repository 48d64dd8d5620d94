"""The grid world's training scan schedule (``SimConfig.scan_travel``): scans by travel,
denser, and one before each decision."""

import dataclasses
import math

import numpy as np
import pytest

from mjexplore.config import load_yaml_config
from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.grid_world import GridWorld
from mjexplore.sim.simulator import ScanTravel, SimConfig

TRAVEL = ScanTravel(distance=0.25, angle=0.5, beam_factor=2)


def _drive(world, commands, seconds_each=2.0):
    """Drives each (v, omega) for ``seconds_each`` in 0.1 s control periods; the scans."""
    scans = []
    for v, w in commands:
        for _ in range(round(seconds_each / 0.1)):
            world.command(v, w)
            scans += world.step(0.1)
    return scans


def test_scans_come_by_travel_and_turn(box_room):
    """Driving arcs and turning in place: consecutive scans lie at most the travel (plus
    one scan period's motion) apart, in position and heading, far fewer scans come than at
    10 Hz, and each casts twice the lidar's beams."""
    folder, _ = box_room
    world = GridWorld(folder, SimConfig(dynamics="grid", scan_travel=TRAVEL))
    first = world.reset((1.0, 2.2, 0.0))
    commands = [(0.5, 0.0), (0.3, 0.4), (0.0, 1.8), (0.4, -0.3)]
    scans = [first, *_drive(world, commands)]
    assert world.collisions == 0
    poses = np.array([s.pose for s in scans])
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    turn = np.abs(np.diff(np.unwrap(poses[:, 2])))
    # A scan instant every 0.1 s: at most 0.05 m and 0.18 rad past the thresholds.
    assert step.max() <= TRAVEL.distance + 0.05 + 1e-9
    assert turn.max() <= TRAVEL.angle + 0.18 + 1e-9
    assert ((step >= TRAVEL.distance) | (turn >= TRAVEL.angle)).all()
    assert len(scans) < 8 * 10 / 3  # 8 s at 10 Hz would be 80 scans.
    assert all(len(s.ranges) == 720 == len(s.angles) for s in scans)
    assert np.allclose(np.diff(scans[0].angles), math.pi / 360)


def test_scan_now_takes_the_skipped_scan_once(box_room):
    folder, _ = box_room
    world = GridWorld(folder, SimConfig(dynamics="grid", scan_travel=TRAVEL))
    world.reset((1.0, 2.2, 0.0))
    world.command(0.3, 0.0)
    scans = world.step(0.4)  # 0.1 m or less: short of the travel.
    assert scans == []
    now = world.scan_now()
    assert now is not None and now.stamp == pytest.approx(world.time)
    assert now.pose[2] == pytest.approx(world.pose[2])
    # Posed at the lidar on the base as it stands now.
    assert np.hypot(*(now.pose[:2] - world.pose[:2])) == pytest.approx(
        np.hypot(*TURTLEBOT3_WAFFLE.scan_offset[:2]))
    assert world.latest_scan is now and world.scan_now() is None
    plain = GridWorld(folder, SimConfig(dynamics="grid"))
    plain.command(0.3, 0.0)
    assert len(plain.step(0.4)) == 4 and plain.scan_now() is None


def test_scan_travel_is_refused_outside_the_grid_world():
    for dynamics in ("physics", "kinematic"):
        with pytest.raises(UserInputError, match="grid-world setting"):
            SimConfig(dynamics=dynamics, scan_travel=TRAVEL)
    with pytest.raises(UserInputError, match="beam_factor"):
        ScanTravel(beam_factor=0)


def test_the_grid_training_config_scans_by_travel():
    """training/gvn_v2.yaml trains, and selects its model, in the grid world with the
    travel schedule."""
    from mjexplore.learning.train_config import TrainConfig

    config = load_yaml_config(TrainConfig, "training/gvn_v2.yaml")
    for episode in (config.env.episode, config.eval.episode):
        assert episode.sim.dynamics == "grid"
        assert episode.sim.scan_travel == ScanTravel()


def test_episode_scans_at_every_decision_and_explores(tmp_path):
    """A nearest-frontier episode in the grid world with the travel schedule explores a
    generated layout to the target; a scan is mapped at the instant of every decision,
    and the map gets far fewer scans than the lidar's rate would give."""
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.episode.nearest import NearestFrontier

    scene = load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                         tmp_path / "rooms"))
    config = EpisodeConfig(max_time=600.0, sim=SimConfig(dynamics="grid", scan_travel=TRAVEL))
    episode = Episode(scene, NearestFrontier(), 3, config)
    result = episode.run()
    assert result.metrics["end_reason"] == "explored"
    stamps = result.ratio_curve[:, 0]
    decided = result.goals[:, 0]
    assert len(decided) >= 3
    assert np.isin(np.round(decided, 6), np.round(stamps, 6)).all()
    assert len(stamps) < result.metrics["exploration_time_s"] * 10 / 3
    # Without the schedule the same episode scans at 10 Hz.
    plain = Episode(scene, NearestFrontier(), 3, dataclasses.replace(
        config, sim=SimConfig(dynamics="grid"), max_time=5.0)).run()
    assert len(plain.ratio_curve) == 51
