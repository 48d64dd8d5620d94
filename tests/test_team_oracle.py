"""The team oracle: the ground-truth plan's viewpoints split into min-max routes, and an
oracle team that explores."""

from __future__ import annotations

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.team import TeamConfig
from mjexplore.errors import UserInputError
from mjexplore.explorers.team import make_team_explorers
from mjexplore.explorers.team_oracle import OracleMember, route_length, split_routes
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig


def _line(robots, viewpoints):
    """Path lengths between points on a line (robots first)."""
    x = np.array([*robots, *viewpoints], float)
    return np.abs(x[:, None] - x[None, :])


def test_routes_split_a_corridor_between_robots_at_its_ends():
    d = _line([0.0, 10.0], [1, 2, 3, 4, 6, 7, 8, 9])
    routes = split_routes(d, 2)
    assert sorted(routes[0]) == [2, 3, 4, 5] and sorted(routes[1]) == [6, 7, 8, 9]
    assert max(route_length(d, k, r) for k, r in enumerate(routes)) == pytest.approx(4.0)
    # One robot alone takes every viewpoint; the longest route of two is shorter.
    alone = split_routes(_line([0.0], [1, 2, 3, 4, 6, 7, 8, 9]), 1)
    assert sorted(alone[0]) == list(range(1, 9))


def test_a_pinned_viewpoint_stays_first_on_its_route():
    d = _line([0.0, 10.0], [1, 2, 8, 9])
    routes = split_routes(d, 2, pinned={0: 4})  # Robot 0 already drives to x = 8.
    assert routes[0][0] == 4 and sorted(p for r in routes for p in r) == [2, 3, 4, 5]


def test_an_oracle_team_explores(tmp_path):
    scene = load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                         tmp_path / "scene"))
    explorers = make_team_explorers("oracle", 2)
    assert all(isinstance(e, OracleMember) for e in explorers)
    assert explorers[0].coordinator is explorers[1].coordinator
    config = EpisodeConfig(sim=SimConfig(dynamics="kinematic"))
    episode = Episode(scene, explorers, 0, config)
    metrics = episode.run().metrics
    assert metrics["end_reason"] == "explored" and metrics["robot_collisions"] == 0
    assert explorers[0].coordinator.splits >= 2
    assert all(r["decisions"] >= 1 for r in metrics["per_robot"])
    with pytest.raises(UserInputError, match="unknown-starts"):
        Episode(scene, make_team_explorers("oracle", 2), 0, config,
                team_config=TeamConfig(unknown_starts=True))
