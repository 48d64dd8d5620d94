"""Mesh worlds: building models imported as scenes, scenes exported as meshes."""

import json
import logging
import math
import os

import mujoco
import numpy as np
import pytest
import trimesh

from mjexplore.cli import main
from mjexplore.maps import UNKNOWN
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.mesh import MeshImportConfig, cluster_simplify, scene_from_mesh
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig, Simulator

# The test building: 10 x 8 m, four rooms joined by 1 m doors, a pillar; walls 0.2 m thick
# and 2.5 m tall as boxes [x0, y0, x1, y1] (metres), on a 0.1 m floor slab.
WALLS = np.array([
    (0, 0, 10, 0.2), (0, 7.8, 10, 8), (0, 0, 0.2, 8), (9.8, 0, 10, 8),  # outer walls
    (4.9, 0.2, 5.1, 2.0), (4.9, 3.0, 5.1, 7.8),                          # x = 5, door y 2..3
    (5.1, 3.9, 7.0, 4.1), (8.0, 3.9, 9.8, 4.1),                          # y = 4, door x 7..8
    (0.2, 4.9, 2.0, 5.1), (3.0, 4.9, 4.9, 5.1),                          # y = 5, door x 2..3
    (7.3, 1.5, 7.7, 1.9),                                                # a pillar
])
WALL_HEIGHT = 2.5
Y_UP = trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0])  # z-up -> y-up
RANGE_MAX = 6.0


def building_parts(walls=WALLS):
    parts = []
    for x0, y0, x1, y1 in walls:
        box = trimesh.creation.box(extents=[x1 - x0, y1 - y0, WALL_HEIGHT])
        box.apply_translation([(x0 + x1) / 2, (y0 + y1) / 2, WALL_HEIGHT / 2])
        parts.append(box)
    slab = trimesh.creation.box(extents=[10, 8, 0.1])
    slab.apply_translation([5, 4, -0.05])
    return parts + [slab]


def write_building(path, parts=None):
    """Writes the building y-up (as glTF and OBJ files are), each part centred on its
    node's origin and placed by the node's transform (OBJ files get them applied)."""
    scene = trimesh.Scene()
    for i, part in enumerate(parts or building_parts()):
        centre = part.bounds.mean(axis=0)
        part = part.copy()
        part.apply_translation(-centre)
        place = Y_UP @ trimesh.transformations.translation_matrix(centre)
        scene.add_geometry(part, node_name=f"part{i}", geom_name=f"part{i}", transform=place)
    scene.export(str(path))
    return path


def cell_centres(grid):
    rows, cols = np.indices(grid.shape)
    return (grid.origin[0] + (cols + 0.5) * grid.resolution,
            grid.origin[1] + (rows + 0.5) * grid.resolution)


def inside_boxes(x, y, boxes):
    hit = np.zeros(x.shape, dtype=bool)
    for x0, y0, x1, y1 in boxes:
        hit |= (x > x0) & (x < x1) & (y > y0) & (y < y1)
    return hit


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def ray_box_ranges(origin, angles, boxes):
    """Distances from ``origin`` along each angle to the nearest box (inf if none)."""
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (boxes[None, :, :2] - origin) / d[:, None, :]
        t1 = (boxes[None, :, 2:] - origin) / d[:, None, :]
    near = np.nanmax(np.minimum(t0, t1), axis=2)
    far = np.nanmin(np.maximum(t0, t1), axis=2)
    hit = (near <= far) & (far > 0)
    return np.where(hit, np.maximum(near, 0), np.inf).min(axis=1)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("building")
    return {"glb": write_building(folder / "building.glb"),
            "obj": write_building(folder / "building.obj")}


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_import_matches_the_construction(files, fmt):
    scene = scene_from_mesh(files[fmt], seed=0)
    gt = scene.ground_truth
    x, y = cell_centres(gt)
    building = (x > 0) & (x < 10) & (y > 0) & (y < 8)
    expected_free = building & ~inside_boxes(x, y, WALLS)
    assert iou(gt.free, expected_free) >= 0.95
    assert gt.occupied[inside_boxes(x, y, WALLS)].all()  # Thick walls are solid.
    assert (gt.data[~building] == UNKNOWN).all()
    assert scene.metadata["up_axis"] == "y" and scene.metadata["floor_z"] == pytest.approx(0)
    assert scene.metadata["unreachable_room_area_m2"] == 0


def test_mjcf_compiles_and_the_lidar_sees_the_walls(files, tmp_path):
    scene = scene_from_mesh(files["glb"], seed=3)
    write_scene(scene, tmp_path / "scene")
    assert (tmp_path / "scene" / "building.stl").is_file()
    sim = Simulator(load_scene_files(tmp_path / "scene"), SimConfig())
    building = sim.model.geom("building")
    assert building.type == mujoco.mjtGeom.mjGEOM_MESH
    assert (building.group, building.contype, building.conaffinity) == (2, 0, 0)
    scan = sim.reset()
    expected = ray_box_ranges(scan.pose[:2], scan.angles + scan.pose[2], WALLS)
    seen = expected < RANGE_MAX - 0.1
    assert seen.sum() > 180
    np.testing.assert_allclose(scan.ranges[seen], expected[seen], atol=0.02)
    assert np.isinf(scan.ranges[expected > RANGE_MAX + 0.1]).all()


def test_zero_thickness_walls_of_a_turned_building(tmp_path):
    # Walls as single planes (as in scans), the building turned by 30 degrees.
    lines = [((0, 0), (10, 0)), ((10, 0), (10, 8)), ((10, 8), (0, 8)), ((0, 8), (0, 0)),
             ((5, 0), (5, 2)), ((5, 3), (5, 8)), ((5, 4), (7, 4)), ((8, 4), (10, 4))]
    parts = [trimesh.Trimesh([[*a, 0], [*b, 0], [*b, 2.5], [*a, 2.5]], [[0, 1, 2], [0, 2, 3]])
             for a, b in lines]
    parts.append(trimesh.Trimesh([[0, 0, 0], [10, 0, 0], [10, 8, 0], [0, 8, 0]],
                                 [[0, 1, 2], [0, 2, 3]]))
    mesh = trimesh.util.concatenate(parts)
    turn = trimesh.transformations.rotation_matrix(math.radians(30), [0, 0, 1])
    mesh.apply_transform(turn)
    mesh.export(tmp_path / "thin.ply")
    scene = scene_from_mesh(tmp_path / "thin.ply")
    gt = scene.ground_truth
    x, y = cell_centres(gt)
    u = x * math.cos(math.radians(30)) + y * math.sin(math.radians(30))  # Building frame.
    v = -x * math.sin(math.radians(30)) + y * math.cos(math.radians(30))
    assert not gt.free[(u < 0) | (u > 10) | (v < 0) | (v > 8)].any()  # No leak outside.
    area = gt.free.sum() * gt.resolution ** 2
    assert 76.0 < area < 80.0  # 80 m2 less the walls' cells, all four rooms reached.


def test_a_closed_room_is_reported_and_walled(tmp_path, caplog):
    closed = np.vstack([WALLS, [(2.0, 4.9, 3.0, 5.1)]])  # The door at y = 5 walled up.
    path = write_building(tmp_path / "closed.glb", building_parts(closed))
    with caplog.at_level(logging.WARNING):
        scene = scene_from_mesh(path, seed=0)
    room = 4.7 * 2.7  # 0.2..4.9 x 5.1..7.8
    assert scene.metadata["unreachable_room_area_m2"] == pytest.approx(room, rel=0.05)
    assert "cannot reach" in caplog.text
    x, y = cell_centres(scene.ground_truth)
    in_room = (x > 0.2) & (x < 4.9) & (y > 5.1) & (y < 7.8)
    assert scene.ground_truth.occupied[in_room].all()


def test_export_of_a_generated_scene_has_its_wall_footprint(tmp_path, capsys):
    out, glb = tmp_path / "rooms", tmp_path / "rooms.glb"
    assert main(["scene-gen", "rooms", "--size", "12x10", "--seed", "1", "--out", str(out),
                 "--export", str(glb)]) == 0
    assert json.loads(capsys.readouterr().out)["export"] == str(glb)
    gt = load_scene_files(out).ground_truth
    loaded = trimesh.load(glb, force="scene")
    walls, floor = loaded.geometry["walls"], loaded.geometry["floor"]
    # glTF is y-up: heights along +y, the map's y along -z.
    assert walls.bounds[:, 1] == pytest.approx([0.0, 3.0])
    assert floor.bounds[1, 1] == pytest.approx(0.0)
    assert walls.bounds[:, 0] == pytest.approx([0.0, 12.0])
    assert walls.bounds[:, 2] == pytest.approx([-10.0, 0.0])
    walls = walls.copy()
    walls.apply_transform(np.linalg.inv(Y_UP))
    # Slice every wall box at 1 m and fill the cells whose centres its section holds.
    x, y = cell_centres(gt)
    footprint = np.zeros(gt.shape, dtype=bool)
    for box in walls.split(only_watertight=False):
        section = trimesh.intersections.mesh_plane(box, [0, 0, 1], [0, 0, 1.0])[:, :, :2]
        (x0, y0), (x1, y1) = section.reshape(-1, 2).min(0), section.reshape(-1, 2).max(0)
        footprint |= (x > x0) & (x < x1) & (y > y0) & (y < y1)
    assert iou(footprint, gt.occupied) >= 0.98


def test_export_of_an_existing_scene_imports_back(tmp_path, capsys):
    obj = tmp_path / "loop.obj"
    assert main(["scene-gen", "--from-scene", "train_loop", "--export", str(obj)]) == 0
    capsys.readouterr()
    back = scene_from_mesh(obj).ground_truth  # OBJ: written and read y-up.
    original = resolve_scene("train_loop").ground_truth
    offset = np.round(np.subtract(original.origin[:2], back.origin[:2]) / back.resolution)
    c, r = offset.astype(int)
    window = back.data[r:r + original.shape[0], c:c + original.shape[1]]
    assert iou(window == 0, original.free) >= 0.98


def test_bad_meshes_exit_2_with_a_message(tmp_path, capsys):
    def run(path, *extra):
        code = main(["scene-gen", "--from-mesh", str(path), "--out", str(tmp_path / "o"),
                     *extra])
        return code, capsys.readouterr().err

    junk = tmp_path / "junk.glb"
    junk.write_bytes(os.urandom(4096))
    code, err = run(junk)
    assert code == 2 and "could not be read as GLB" in err
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")  # Points, no faces.
    code, err = run(empty)
    assert code == 2 and "no triangles" in err
    slab = tmp_path / "slab.stl"
    building_parts()[-1].export(slab)  # A floor and nothing on it.
    code, err = run(slab)
    assert code == 2 and "has nothing at 0.132 m above its floor" in err
    wall = tmp_path / "wall.stl"
    building_parts()[0].export(wall)  # One wall: nothing enclosed, no floor.
    code, err = run(wall)
    assert code == 2 and "no floor area" in err
    mm = tmp_path / "mm.stl"
    trimesh.util.concatenate(building_parts()).apply_scale(1000).export(mm)
    code, err = run(mm)
    assert code == 2 and "looks like millimetres, pass --mesh-units mm" in err
    code, _ = run(mm, "--mesh-units", "mm")
    assert code == 0
    code, err = run(mm, "--mesh-units", "mm", "--mesh-scale", "0.001")
    assert code == 2 and "not both" in err


def test_mesh_options_need_a_mesh(tmp_path, capsys):
    assert main(["scene-gen", "office", "--up-axis", "z", "--out", str(tmp_path / "o")]) == 2
    assert "--up-axis apply to --from-mesh only" in capsys.readouterr().err
    assert main(["scene-gen", "--from-scene", "train_loop", "--export", "x.dae"]) == 2
    assert "give a file ending in .glb" in capsys.readouterr().err


def test_cluster_simplify_keeps_the_shape_within_budget():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=2.0)  # 20,480 triangles
    small = cluster_simplify(sphere, 2000)
    assert 500 < len(small.faces) <= 2000
    assert small.bounds == pytest.approx(sphere.bounds, abs=0.2)
    assert small.area == pytest.approx(sphere.area, rel=0.1)


def test_config_is_checked():
    with pytest.raises(ValueError, match="positive"):
        MeshImportConfig(scale=0)
    with pytest.raises(ValueError, match="out of range"):
        MeshImportConfig(resolution=2.0)


@pytest.mark.slow
def test_nearest_explores_the_imported_building(files, tmp_path):
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer

    write_scene(scene_from_mesh(files["glb"], seed=0), tmp_path / "scene")
    result = Episode(load_scene_files(tmp_path / "scene"), make_explorer("nearest"), 0,
                     EpisodeConfig()).run()
    m = result.metrics
    assert m["end_reason"] == "explored" and m["exploration_ratio"] >= 0.985
    assert m["collisions"] == 0
