"""Map-to-map merging: a map seen in another frame is placed back where it belongs, a wrong
placement fails the verification, too little overlap is no answer; and a team with unknown
start poses merges its maps and explores."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.team import TeamConfig
from mjexplore.eval.methods import team_explorers
from mjexplore.mapping.map_merging import (
    MapMergeConfig,
    merge_maps,
    pool_grid,
    rotation_candidates,
    verify_merge,
)
from mjexplore.maps import GridMap
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig


def _seen_from(truth: GridMap, frame, extent, keep) -> GridMap:
    """``truth`` drawn in the frame whose pose in ``truth``'s frame is ``frame``: a grid
    over ``extent`` (x0, y0, width, height; that frame, metres), unknown outside the
    ``keep`` box (xmin, xmax, ymin, ymax; ``truth``'s frame)."""
    res = truth.resolution
    x0, y0, w, h = extent
    r, c = np.mgrid[0:round(h / res), 0:round(w / res)]
    px, py = x0 + (c + 0.5) * res, y0 + (r + 0.5) * res
    cs, sn = math.cos(frame[2]), math.sin(frame[2])
    wx, wy = frame[0] + cs * px - sn * py, frame[1] + sn * px + cs * py
    values = truth.value_at(np.stack([wx, wy], -1))
    inside = (wx >= keep[0]) & (wx <= keep[1]) & (wy >= keep[2]) & (wy <= keep[3])
    return GridMap(np.where(inside, values, -1).astype(np.int8), res, (x0, y0, 0.0))


@pytest.fixture(scope="module")
def office():
    return resolve_scene("office").ground_truth


def test_a_map_seen_in_another_frame_is_placed_back(office):
    a = _seen_from(office, (0.0, 0.0, 0.0), (0, 0, 40, 25), (0, 22, 0, 25))
    frame = np.array([18.3, 9.7, math.radians(127.0)])  # b's frame in a's.
    b = _seen_from(office, frame, (-25, -25, 50, 50), (14, 40, 0, 25))
    match = merge_maps(a, b)
    assert match.accepted
    assert np.hypot(*(match.pose[:2] - frame[:2])) < 0.05
    assert abs(math.degrees(match.pose[2] - frame[2])) < 0.3
    # A wrong placement (half a metre off, or turned 2 degrees) does not verify.
    cfg = MapMergeConfig()
    for wrong in (frame + [0.5, 0, 0], frame + [0, 0, math.radians(2.0)]):
        inliers, conflict, _, _ = verify_merge(a, b, wrong, cfg)
        assert inliers < cfg.min_inliers or conflict > cfg.max_conflict


def test_maps_that_do_not_overlap_are_not_merged(office):
    a = _seen_from(office, (0.0, 0.0, 0.0), (0, 0, 40, 25), (0, 14, 0, 25))
    b = _seen_from(office, (30.0, 12.0, 1.0), (-25, -25, 50, 50), (26, 40, 0, 25))
    assert not merge_maps(a, b).accepted


def test_rotation_candidates_include_the_true_turn(office):
    points = pool_grid(office, 0.2)
    xy = points.cell_to_world(np.argwhere(points.occupied))
    turn = math.radians(73.0)
    c, s = math.cos(turn), math.sin(turn)
    turned = xy @ np.array([[c, -s], [s, c]])  # Rotated by -turn: b = R(-turn) a.
    candidates = rotation_candidates(xy, turned, 0.2, 4)
    gap = np.abs((candidates - turn + math.pi) % (2 * math.pi) - math.pi)
    assert gap.min() < math.radians(1.0)


def test_a_team_with_unknown_starts_merges_and_explores(tmp_path):
    scene = load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                         tmp_path / "scene"))
    explorers, _ = team_explorers("assign_greedy", 2)
    episode = Episode(scene, explorers, 0, EpisodeConfig(sim=SimConfig(dynamics="kinematic")),
                      team_config=TeamConfig(unknown_starts=True))
    assert not episode.merging.merged[1] and episode.agents[1].mapper is episode.team.own[1]
    metrics = episode.run().metrics
    assert metrics["end_reason"] == "explored" and metrics["merged"]
    assert metrics["merge_error_m"] <= 0.05 and metrics["merge_error_deg"] <= 0.5
    assert 0 < metrics["merge_time_s"] <= metrics["t985_s"]
    assert episode.agents[1].mapper is episode.mapper
    assert metrics["team_map_ratio"] >= 0.985


def test_a_merged_robots_scans_are_aligned_to_the_team_map(tmp_path):
    scene = load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                         tmp_path / "scene"))
    explorers, _ = team_explorers("assign_greedy", 2)
    episode = Episode(scene, explorers, 0, EpisodeConfig(sim=SimConfig(dynamics="kinematic")),
                      team_config=TeamConfig(unknown_starts=True))
    while not episode.merging.merged[1]:
        assert episode.step()
    for _ in range(20):
        episode.step()
    scan = episode.world.robots[1].latest_scan
    # An estimate 4 cm off: the scan match puts the scan back where it was taken.
    robot, merging = episode.agents[1], episode.merging
    robot.correction = np.array([0.04, 0.0, 0.0])
    aligned = merging._merged_pose(episode.mapper, robot, scan)
    assert np.hypot(*(aligned[:2] - scan.pose[:2])) < 0.02
    assert merging.aligned_scans > 0
    # Nor does a scan mapped from a wrong pose turn the team's walls free.
    robot.correction = np.array([0.1, -0.05, 0.02])
    walls = episode.mapper.grid.occupied.copy()
    merging.integrate_merged(episode.mapper, robot, scan)
    assert episode.mapper.grid.occupied[walls].all()
