"""The ``dungeon`` scene family: rooms of varied sizes joined by corridors (roguelike)."""

import json

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.generators import (
    DUNGEON_MIN_WALL,
    GeneratorConfig,
    generate_solid,
    parse_family,
)
from mjexplore.scenes.map_server import read_map
from mjexplore.scenes.scene import build_spec, clearance, unreachable_share, write_scene
from mjexplore.sim.simulator import Simulator

RESOLUTION = 0.05
# The procedural training range (training/gvn_v3.yaml): width 12-40 m, height 10-25 m.
SMALLEST, LARGEST = (12.0, 10.0), (40.0, 25.0)


def _solid(width, height, seed, config=None):
    """The generator's own wall grid, before the pipeline fills unreachable pockets."""
    return generate_solid("dungeon", width, height, RESOLUTION, np.random.default_rng(seed),
                          config or GeneratorConfig())


def _room_cores(free):
    """Free space too wide for any one corridor (over the widest corridor's half width from
    a wall), labelled: (labels, count)."""
    widest_corridor = GeneratorConfig().loop_corridor_width[1]
    return ndimage.label(clearance(free, RESOLUTION) > widest_corridor / 2 + 0.1)


def test_family_is_registered_and_combines():
    assert parse_family("dungeon") == ["dungeon"]
    assert parse_family("loop+dungeon") == ["loop", "dungeon"]


def test_same_seed_same_layout_other_seed_another():
    a = generate_scene("dungeon", 30, 20, seed=7)
    b = generate_scene("dungeon", 30, 20, seed=7)
    c = generate_scene("dungeon", 30, 20, seed=8)
    assert np.array_equal(a.solid, b.solid) and a.start == b.start
    assert not np.array_equal(a.solid, c.solid)


@pytest.mark.parametrize("size", [SMALLEST, (30.0, 20.0), LARGEST, (12.0, 25.0)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_free_space_is_one_region_the_robot_reaches_everywhere(size, seed):
    solid = _solid(*size, seed)
    free = ~solid
    assert ndimage.label(free)[1] == 1
    # The generator's own output, not the pipeline's pocket filling, must be reachable: every
    # corridor and opening lets the footprint through.
    assert unreachable_share(solid, RESOLUTION) == 0.0
    assert solid[0].all() and solid[-1].all() and solid[:, 0].all() and solid[:, -1].all()
    assert 0.2 < free.mean() < 0.7


@pytest.mark.parametrize("size, least_rooms", [(SMALLEST, 2), ((30.0, 20.0), 3),
                                               (LARGEST, 5)])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_several_rooms_joined_by_corridors_narrower_than_rooms(size, least_rooms, seed):
    free = ~_solid(*size, seed)
    cores, n_cores = _room_cores(free)
    # A core at least the smallest room side across is a room (corridors that run side by
    # side and merge can make a core too, but a narrower one).
    widest = ndimage.maximum(clearance(free, RESOLUTION), cores, range(1, n_cores + 1))
    rooms = np.sum(np.asarray(widest) >= GeneratorConfig().room_size[0] / 2 - 2 * RESOLUTION)
    assert rooms >= least_rooms
    # Separate cores in one free region: what joins the rooms is narrower than any room.
    assert ndimage.label(free)[1] == 1


# Seeds whose corridors leave walls of 0.15-0.5 m before the generator opens them.
@pytest.mark.parametrize("seed", [5, 6, 10])
def test_no_wall_is_thinner_than_the_minimum(seed):
    solid = _solid(30, 20, seed)
    cells = round(DUNGEON_MIN_WALL / RESOLUTION)
    # An opening removes every solid feature thinner than its square; the outer wall touches
    # the border, which counts as solid.
    opened = ndimage.binary_opening(solid, np.ones((cells, cells), bool), border_value=True)
    assert np.array_equal(opened, solid)


@settings(max_examples=12, deadline=None)
@given(width=st.floats(12.0, 40.0), height=st.floats(10.0, 25.0),
       seed=st.integers(0, 2**31 - 1), thickness=st.sampled_from([0.1, 0.15, 0.3]))
def test_any_training_size_gives_a_connected_layout(width, height, seed, thickness):
    solid = _solid(width, height, seed, GeneratorConfig(wall_thickness=thickness))
    assert ndimage.label(~solid)[1] == 1
    assert unreachable_share(solid, RESOLUTION) == 0.0


@pytest.mark.parametrize("family, size", [("dungeon+rooms", (30, 15)),
                                          ("office+dungeon", (40, 25)),
                                          ("maze+dungeon+loop", (40, 18))])
def test_combinations_are_connected_and_compile(family, size):
    scene = generate_scene(family, *size, seed=3)
    free = scene.ground_truth.free
    assert ndimage.label(free)[1] == 1
    start_cell = tuple(scene.ground_truth.world_to_cell(np.array(scene.start[:2])))
    assert clearance(free, RESOLUTION)[start_cell] > TURTLEBOT3_WAFFLE.footprint_radius
    model = build_spec(scene).compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=20)
    assert not any(w.number for w in data.warning)


def test_robot_drives_without_warnings(tmp_path):
    scene = generate_scene("dungeon", 20, 15, seed=0)
    sim = Simulator(write_scene(scene, tmp_path / "dungeon"))
    rng = np.random.default_rng(0)
    for _ in range(150):  # 15 s of random driving, bumping into walls included.
        sim.command(rng.uniform(-0.5, 0.5), rng.uniform(-1.8, 1.8))
        sim.step(0.1)
    assert sim.warnings() == {}
    assert sim.is_upright


def test_a_part_narrower_than_the_smallest_room_is_refused():
    with pytest.raises(UserInputError, match="dungeon needs at least"):
        generate_scene("dungeon+dungeon", 6, 4, seed=0)


def test_scene_gen_cli_writes_a_dungeon(tmp_path):
    out = tmp_path / "dungeon"
    assert main(["scene-gen", "dungeon", "--seed", "0", "--size", "30x20",
                 "--out", str(out)]) == 0
    assert (out / "scene.xml").is_file() and (out / "map.pgm").is_file()
    assert json.loads((out / "scene.json").read_text())["family"] == "dungeon"
    grid = read_map(out / "map.yaml")
    assert grid.size_m == pytest.approx((30, 20))
    expected = generate_scene("dungeon", 30, 20, seed=0).ground_truth
    assert np.array_equal(grid.free, expected.free)
