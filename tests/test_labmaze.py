"""The ``labmaze`` scene family (DeepMind Lab's maze generator).

Determinism (same seed, same files) is checked with the other families in test_scenes.py.
"""

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.generators import GeneratorConfig, generate_solid
from mjexplore.scenes.labmaze_family import LabmazeConfig, entity_layer
from mjexplore.scenes.scene import build_spec, clearance, reachable_region

SIZES = [(6, 5), (14, 12), (20, 20), (31, 17)]


def _assert_valid(scene):
    grid = scene.ground_truth
    free = grid.free
    assert ndimage.label(free)[1] == 1, "free space must be one connected region"
    start = tuple(grid.world_to_cell(np.array(scene.start[:2])))
    assert clearance(free, grid.resolution)[start] > TURTLEBOT3_WAFFLE.footprint_radius
    _, reach = reachable_region(free, grid.resolution, start)
    assert reach.sum() == free.sum(), "the footprint must reach every free cell"
    assert scene.solid[0].all() and scene.solid[-1].all()
    assert scene.solid[:, 0].all() and scene.solid[:, -1].all()
    assert 0.2 < free.mean() < 0.98


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("seed", range(8))
def test_labmaze_scenes_are_connected_with_a_free_start(size, seed):
    _assert_valid(generate_scene("labmaze", *size, seed=seed))


@pytest.mark.parametrize("family, size", [("labmaze+rooms", (26, 14)),
                                          ("maze+labmaze+corridor", (40, 18))])
@pytest.mark.parametrize("seed", range(2))
def test_labmaze_combines_with_other_families(family, size, seed):
    _assert_valid(generate_scene(family, *size, seed=seed))


@settings(max_examples=25, deadline=None)
@given(width=st.floats(4.0, 30.0), height=st.floats(4.0, 30.0), seed=st.integers(0, 2**31 - 1),
       thickness=st.sampled_from([0.1, 0.15, 0.3]), cell=st.sampled_from([1.2, 1.5, 2.0]),
       simplify=st.booleans(), extra=st.sampled_from([0.0, 0.1, 0.5]))
def test_any_valid_labmaze_parameters_give_a_valid_compilable_scene(width, height, seed,
                                                                    thickness, cell, simplify,
                                                                    extra):
    lm = LabmazeConfig(cell=cell, simplify=simplify, extra_connection_probability=extra)
    scene = generate_scene("labmaze", width, height, seed=seed,
                           config=GeneratorConfig(wall_thickness=thickness, labmaze=lm))
    _assert_valid(scene)
    model = build_spec(scene).compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=20)
    assert not any(w.number for w in data.warning)


@pytest.mark.parametrize("width, height, seed", [(20, 20, 0), (14, 9, 5), (31, 17, 11)])
def test_layout_is_labmazes_entity_layer_scaled_to_cells(width, height, seed):
    cfg = GeneratorConfig()
    res = 0.05
    solid = generate_solid("labmaze", width, height, res, np.random.default_rng(seed), cfg)
    # generate_scene's rng draws labmaze's seed first; text row 0 is the north edge.
    labmaze_seed = int(np.random.default_rng(seed).integers(2**31))
    half = cfg.wall_thickness / 2
    x0, y0 = half, half
    w, h = width - cfg.wall_thickness, height - cfg.wall_thickness
    nx, ny = int(w // cfg.labmaze.cell), int(h // cfg.labmaze.cell)
    text = entity_layer(nx, ny, labmaze_seed, cfg.labmaze)
    assert text.shape == (2 * ny + 1, 2 * nx + 1)
    # The centre of text column c: a wall line (even c) or the middle of a cell (odd c).
    xs = x0 + np.arange(2 * nx + 1) / 2 * (w / nx)
    ys = y0 + h - np.arange(2 * ny + 1) / 2 * (h / ny)
    cols = np.floor(xs / res).astype(int)
    rows = np.floor(ys / res).astype(int)
    sampled = solid[np.clip(rows, 0, solid.shape[0] - 1)[:, None],
                    np.clip(cols, 0, solid.shape[1] - 1)[None, :]]
    expected = text == "*"
    assert expected[1:-1, 1:-1].any() and not expected[1:-1, 1:-1].all()
    np.testing.assert_array_equal(sampled, expected)
    # The validated scene only fills pockets the robot cannot reach: never opens a wall.
    scene = generate_scene("labmaze", width, height, seed=seed)
    assert np.all(scene.solid[solid])


def test_knobs_reach_labmaze():
    base = generate_scene("labmaze", 20, 20, seed=0)
    full = generate_scene("labmaze", 20, 20, seed=0,
                          config=GeneratorConfig(labmaze=LabmazeConfig(simplify=False)))
    # Without simplify labmaze keeps its dead ends: more of the area is free.
    assert full.ground_truth.free.mean() > base.ground_truth.free.mean() + 0.1
    assert base.metadata["generator_config"]["labmaze"]["simplify"] is True
    assert full.metadata["generator_config"]["labmaze"]["simplify"] is False
    one = entity_layer(9, 9, 0, LabmazeConfig(max_rooms=1, simplify=False))
    many = entity_layer(9, 9, 0, LabmazeConfig(max_rooms=20, simplify=False))
    assert not np.array_equal(one, many)


@pytest.mark.parametrize("kwargs, match", [
    (dict(cell=0.5), "labmaze cell"),
    (dict(max_rooms=0), "max_rooms"),
    (dict(room_cells=(1, 3)), "room_cells"),
    (dict(room_cells=(3, 2)), "room_cells"),
    (dict(extra_connection_probability=1.5), "extra_connection_probability"),
    (dict(cells_per_room=0), "cells_per_room"),
])
def test_bad_labmaze_config(kwargs, match):
    with pytest.raises(UserInputError, match=match):
        LabmazeConfig(**kwargs)


@pytest.mark.parametrize("size, config, match", [
    ((4, 20), GeneratorConfig(labmaze=LabmazeConfig(cell=2.5)), "at least 2 x 2 cells"),
    ((20, 20), GeneratorConfig(wall_thickness=1.0), "too narrow"),
])
def test_labmaze_too_small_or_too_narrow(size, config, match):
    with pytest.raises(UserInputError, match=match):
        generate_scene("labmaze", *size, seed=0, config=config)
