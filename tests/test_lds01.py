"""The LDS-01 lidar model: noise, dropouts, range limits and motion skew."""

import dataclasses
import json
import math

import numpy as np
import pytest
from test_lidar import analytic_ranges

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.mapping.occupancy import MapperConfig, OccupancyMapper
from mjexplore.sim.lidar import (
    LDS01,
    LaserScan,
    LidarConfig,
    dropout_probability,
    lidar_model,
    measure_ranges,
)
from mjexplore.sim.simulator import SimConfig, Simulator

EXACT = dict(noise_std=0.0, noise_rel=0.0, dropout_prob=0.0, grazing_start=math.pi / 2,
             grazing_full=math.pi / 2)


def incidence(origin, heading, angles, interior):
    """Angle between each beam and the normal of the box-room wall it hits, radians."""
    ranges = analytic_ranges(origin, heading, angles, interior)
    hx = origin[0] + ranges * np.cos(heading + angles)
    x0, _, x1, _ = interior
    on_x_wall = np.minimum(np.abs(hx - x0), np.abs(hx - x1)) < 1e-6
    along = np.where(on_x_wall, np.cos(heading + angles), np.sin(heading + angles))
    return np.arccos(np.abs(along))


def test_the_model_is_the_units_datasheet():
    cfg = lidar_model("lds01")
    assert cfg == LDS01 and cfg.model == "lds01"
    assert (cfg.num_beams, cfg.rate_hz, cfg.range_min, cfg.range_max) == (360, 5.0, 0.12, 3.5)
    assert np.diff(cfg.angles) == pytest.approx(math.radians(1.0))
    assert lidar_model("lds01", range_max=7.0).range_max == 7.0
    assert lidar_model("ideal") == LidarConfig()
    with pytest.raises(UserInputError, match="lds02"):
        lidar_model("lds02")
    with pytest.raises(UserInputError, match="dropout_prob"):
        lidar_model("lds01", dropout_prob=1.0)
    with pytest.raises(UserInputError, match="grazing"):
        lidar_model("lds01", grazing_start=1.4, grazing_full=1.3)


def test_noise_matches_the_datasheets_precision_over_many_beams():
    rng = np.random.default_rng(0)
    n = 100_000
    for true, std in [(0.3, 0.010), (0.45, 0.010), (1.0, 0.035), (2.0, 0.070), (3.0, 0.105)]:
        dist = np.full(n, true)
        ranges = measure_ranges(dist, dataclasses.replace(LDS01, dropout_prob=0.0), rng)
        err = ranges.astype(float) - true
        assert np.isfinite(err).all()
        assert abs(err.mean()) < 4 * std / math.sqrt(n)  # Unbiased.
        assert err.std() == pytest.approx(std, rel=0.02)


def test_ideal_noise_draws_as_it_always_has():
    """The paper's tables keep their numbers: same draws for the same seed."""
    dist = np.linspace(0.5, 5.0, 360)
    cfg = LidarConfig(noise_std=0.01)
    ranges = measure_ranges(dist, cfg, np.random.default_rng(7))
    old = dist.astype(np.float32) + np.random.default_rng(7).normal(
        0.0, 0.01, size=360).astype(np.float32)
    assert np.array_equal(ranges, old)


def test_dropout_rates_match_the_configured_ones_over_many_beams():
    rng = np.random.default_rng(1)
    n = 100_000
    cfg = LDS01  # 1 % of any beam; from 70 to 85 degrees of incidence rising to all.
    for degrees, p in [(0.0, 0.01), (60.0, 0.01), (74.5, 1 - 0.99 * 0.7),
                       (80.5, 1 - 0.99 * 0.3), (88.0, 1.0)]:
        cos = np.full(n, math.cos(math.radians(degrees)))
        assert dropout_probability(cfg, cos, n) == pytest.approx(p)
        ranges = measure_ranges(np.full(n, 2.0), cfg, rng, cos)
        assert np.isnan(ranges).mean() == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / n)
                                                        + 1e-9)
    # Beams with no return drop out at the random rate only; their normals mean nothing.
    ranges = measure_ranges(np.full(n, -1.0), cfg, rng, np.zeros(n))
    assert np.isnan(ranges).mean() == pytest.approx(0.01, abs=0.002)
    assert np.isposinf(ranges[~np.isnan(ranges)]).all()


def test_range_limits_of_the_unit():
    cfg = dataclasses.replace(LDS01, **EXACT)
    dist = np.array([0.05, 0.12, 1.0, 3.49, 3.51, -1.0, np.inf])
    ranges = measure_ranges(dist, cfg, np.random.default_rng(0))
    assert np.isneginf(ranges[0]) and ranges[1] == pytest.approx(0.12)
    assert ranges[3] == pytest.approx(3.49) and np.isposinf(ranges[4:]).all()


def test_lds01_scans_in_a_room_have_the_configured_statistics(box_room):
    folder, interior = box_room
    sim = Simulator(folder, SimConfig(lidar=lidar_model("lds01"), seed=2))
    scans = [sim.reset((interior[0] + 0.35, 2.2, 0.0))]
    for _ in range(20):
        scans += sim.step(0.2)
    assert [s.stamp for s in scans[1:3]] == pytest.approx([0.2, 0.4])  # 5 Hz.
    s = scans[-1]
    true = analytic_ranges(s.pose[:2], s.pose[2], s.angles, interior)
    angle = incidence(s.pose[:2], s.pose[2], s.angles, interior)
    ranges = np.stack([sc.ranges for sc in scans])
    # Dropouts: 1 % of the beams plus the glancing ones (here 3.4 % in all).
    hit = true < LDS01.range_max
    p = dropout_probability(LDS01, np.where(hit, np.cos(angle), 1.0), len(true))
    assert p.mean() > 0.03
    assert np.isnan(ranges).mean() == pytest.approx(p.mean(), abs=0.01)
    assert (np.isnan(ranges).mean(axis=0)[p == 1.0] == 1.0).all()
    # Noise of the valid readings: 10 mm up to 0.5 m, 3.5 % of the range beyond.
    err = ranges - true
    near = (true > 0.15) & (true < 0.5)
    far = (true > 0.5) & (true < 3.0)
    assert np.nanstd(err[:, near]) == pytest.approx(0.010, rel=0.1)
    assert np.nanstd(err[:, far] / true[far]) == pytest.approx(0.035, rel=0.1)
    beyond = ranges[:, true > 3.8]
    assert np.isposinf(beyond[~np.isnan(beyond)]).all()  # Beyond 3.5 m: no return.


@pytest.mark.parametrize("v, w", [(0.0, 1.5), (0.3, 0.8)])
def test_motion_skew_casts_each_beam_from_its_own_pose(box_room, v, w):
    """In the kinematic mode the base follows the command exactly: after the ramp, beam i
    was taken at stamp + i * time_increment from the pose on the unicycle's arc."""
    folder, interior = box_room
    cfg = lidar_model("lds01", **EXACT)
    sim = Simulator(folder, SimConfig(lidar=cfg, dynamics="kinematic"))
    sim.reset((3.2, 2.2, 0.0))
    sim.command(v, w)
    scan = sim.step(2.0)[-1]
    assert scan.time_increment == pytest.approx(-0.2 / 360)
    x, y, yaw = sim.pose
    s = scan.time_increment * np.arange(360)  # Beam times relative to the stamp (<= 0).
    heading = yaw + w * s
    if v:
        bx = x + v / w * (np.sin(heading) - math.sin(yaw))
        by = y - v / w * (np.cos(heading) - math.cos(yaw))
    else:
        bx, by = np.full(360, x), np.full(360, y)
    ox = bx - 0.064 * np.cos(heading)  # base_scan is 0.064 m behind base_link.
    oy = by - 0.064 * np.sin(heading)
    expected = np.array([analytic_ranges((ox[i], oy[i]), heading[i], scan.angles[i:i + 1],
                                         interior)[0] for i in range(360)])
    valid = expected < 3.4
    assert np.abs(scan.ranges[valid] - expected[valid]).max() < 0.005  # Chunks: SKEW_CHUNK_S.
    # All beams from the scan's pose would be far off: the skew is real.
    unskewed = analytic_ranges(scan.pose[:2], scan.pose[2], scan.angles, interior)
    assert np.abs(unskewed[valid] - expected[valid]).max() > 0.1
    assert scan.pose == pytest.approx([ox[0], oy[0], math.remainder(heading[0], 2 * math.pi)],
                                      abs=1e-9)


def test_dropouts_clear_nothing_in_the_map(box_room):
    folder, interior = box_room
    sim = Simulator(folder, SimConfig(lidar=lidar_model("lds01", dropout_prob=0.3), seed=1))
    scan = sim.reset((interior[0] + 1.0, 2.2, 0.3))
    dropped = np.isnan(scan.ranges)
    assert 0.2 < dropped.mean() < 0.5
    maps = []
    for keep in (np.ones(360, bool), ~dropped):
        mapper = OccupancyMapper.like(sim.scene.ground_truth,
                                      MapperConfig(resolution=sim.scene.ground_truth.resolution))
        mapper.integrate(LaserScan(scan.stamp, scan.ranges[keep], scan.angles[keep],
                                   scan.range_max, scan.pose))
        maps.append(mapper.state)
    assert np.array_equal(maps[0], maps[1])


def test_cli_lidar_model(tmp_path, capsys):
    out = tmp_path / "drive"
    assert main(["drive", "--scene", "lobby", "--duration", "1", "--lidar-model", "lds01",
                 "--out", str(out)]) == 0
    lidar = json.loads((out / "config.json").read_text())["drive"]["sim"]["lidar"]
    assert lidar["model"] == "lds01" and lidar["range_max"] == 3.5
    capsys.readouterr()
    assert main(["drive", "--scene", "lobby", "--lidar-model", "lds01", "--lidar-noise", "0.02",
                 "--out", str(tmp_path / "bad")]) == 2
    assert "drop --lidar-noise" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
