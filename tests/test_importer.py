import json
import math

import cv2
import mujoco
import numpy as np
import pytest
from conftest import shared_data

from mjexplore.cli import main
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.scenes.map_server import read_map, write_map
from mjexplore.scenes.rectangles import rasterize_rectangles


def wall_cells_of_mjcf(xml, grid):
    """Rasterises the compiled model's wall boxes back onto the map's grid."""
    m = mujoco.MjModel.from_xml_path(str(xml))
    res = grid.resolution
    ox, oy, _ = grid.origin
    rects = []
    for g in range(m.ngeom):
        if m.geom(g).name.startswith("wall_"):
            (x, y, _), (hx, hy, _) = m.geom_pos[g], m.geom_size[g]
            rects.append([round((y - hy - oy) / res), round((x - hx - ox) / res),
                          round((y + hy - oy) / res), round((x + hx - ox) / res)])
    return rasterize_rectangles(np.array(rects), grid.shape)


def assert_within_one_cell(walls, expected):
    diff = walls != expected
    if diff.any():
        # Every mismatch must lie within one cell of the true boundary.
        near = cv2.dilate(expected.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        near &= ~cv2.erode(expected.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert not (diff & ~near).any()


def diagonal_map():
    data = np.full((160, 220), FREE, np.int8)
    data[:4, :] = data[-4:, :] = OCCUPIED
    data[:, :4] = data[:, -4:] = OCCUPIED
    img = np.zeros(data.shape, np.uint8)
    cv2.line(img, (40, 20), (150, 120), 255, 3)  # A diagonal wall.
    cv2.line(img, (180, 150), (210, 60), 255, 2)
    data[img > 0] = OCCUPIED
    data[60:80, 180:200] = UNKNOWN  # An unmapped pocket.
    return GridMap(data, 0.05, (-2.0, -1.0, 0.0))


def test_from_map_reproduces_occupancy(tmp_path):
    grid = diagonal_map()
    write_map(tmp_path / "map.yaml", grid)
    rc = main(["scene-gen", "--from-map", str(tmp_path / "map.yaml"), "--start", "0.5,1.5,0.3",
               "--out", str(tmp_path / "scene")])
    assert rc == 0
    walls = wall_cells_of_mjcf(tmp_path / "scene" / "scene.xml", grid)
    assert_within_one_cell(walls, ~grid.free)
    assert read_map(tmp_path / "scene" / "map.yaml").equals(grid)
    meta = json.loads((tmp_path / "scene" / "scene.json").read_text())
    assert meta["start"] == [0.5, 1.5, 0.3]


def test_imported_maps_with_the_same_yaml_but_other_images_are_other_scenes(tmp_path,
                                                                           monkeypatch):
    import tempfile

    from mjexplore.scenes.canonical import resolve_scene

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "cache"))
    (tmp_path / "cache").mkdir()
    grid = diagonal_map()
    other = grid.data.copy()
    other[100:140, 20:60] = OCCUPIED  # A block the first map lacks.
    for name, data in (("a", grid.data), ("b", other)):
        (tmp_path / name).mkdir()
        write_map(tmp_path / name / "map.yaml", GridMap(data, grid.resolution, grid.origin))
    assert (tmp_path / "a" / "map.yaml").read_bytes() == (tmp_path / "b" / "map.yaml").read_bytes()
    a = resolve_scene(str(tmp_path / "a" / "map.yaml"))
    b = resolve_scene(str(tmp_path / "b" / "map.yaml"))
    assert a.xml != b.xml
    assert a.ground_truth.equals(read_map(tmp_path / "a" / "map.yaml"))
    assert b.ground_truth.equals(read_map(tmp_path / "b" / "map.yaml"))


@pytest.mark.parametrize("name", ["corner", "corridor", "loop", "loop_with_corridor", "room",
                                  "room_with_corner"])
def test_explore_bench_maps_import(tmp_path, name):
    yaml_path = shared_data("explore_bench", f"{name}.yaml")
    grid = read_map(yaml_path)
    assert main(["scene-gen", "--from-map", str(yaml_path), "--out", str(tmp_path / name)]) == 0
    walls = wall_cells_of_mjcf(tmp_path / name / "scene.xml", grid)
    assert_within_one_cell(walls, ~grid.free)
    from mjexplore.sim.simulator import Simulator

    sim = Simulator(tmp_path / name)
    sim.command(0.3, 0.4)
    sim.step(2.0)
    assert sim.warnings() == {}


def test_ariadne_image_imports_with_marker_start(tmp_path):
    png = shared_data("ariadne_test", "img_9900.png")
    assert main(["scene-gen", "--from-map", str(png), "--resolution", "0.1",
                 "--out", str(tmp_path / "a")]) == 0
    meta = json.loads((tmp_path / "a" / "scene.json").read_text())
    color = cv2.imread(str(png), cv2.IMREAD_COLOR)
    rows, cols = np.nonzero(np.all(color == (0, 216, 255), axis=2))
    expect_x = (cols.mean() + 0.5) * 0.1
    expect_y = (color.shape[0] - rows.mean() - 0.5) * 0.1
    assert meta["start"][0] == pytest.approx(expect_x, abs=0.051)
    assert meta["start"][1] == pytest.approx(expect_y, abs=0.051)
    grid = read_map(tmp_path / "a" / "map.yaml")
    assert grid.shape == color.shape[:2]
    free_fraction = grid.free.mean()
    assert 0.10 < free_fraction < 0.40
    assert not math.isnan(meta["start"][2])


def test_imported_scene_cache_is_rebuilt_when_the_import_code_changes(tmp_path, monkeypatch):
    """The cache key of an imported map covers the code and robot model that build the
    scene, so a scene imported by older code is never reused."""
    from mjexplore.scenes import canonical

    image = tmp_path / "m.pgm"
    image.write_bytes(b"P5\n2 2\n255\n" + bytes([254, 254, 254, 0]))
    yaml_path = tmp_path / "m.yaml"
    yaml_path.write_text("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    code = tmp_path / "importer_copy.py"
    code.write_text("# version 1\n")
    monkeypatch.setattr(canonical, "IMPORT_CODE", canonical.IMPORT_CODE + (code,))
    before = canonical._import_digest(yaml_path, None)
    assert canonical._import_digest(yaml_path, None) == before
    code.write_text("# version 2\n")
    assert canonical._import_digest(yaml_path, None) != before
