"""Scenes: a wall grid with its ground truth, a start pose, and the MJCF built from them.

A scene folder holds:
    scene.xml    the MuJoCo model (walls as merged boxes, floor, light and the robot);
    map.yaml/.pgm  the ground-truth map as a ROS map_server pair;
    preview.png  a picture of the ground truth with the start pose;
    scene.json   what made it (family, seed, size, ...) and the start pose;
    building.stl  (scenes from meshes only) the building, shown but not collided with.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any, cast

import cv2
import mujoco
import numpy as np
from scipy import ndimage

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import atomic_directory, write_bytes_atomic, write_text_atomic
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.robot import ROBOT_XML, TURTLEBOT3_WAFFLE
from mjexplore.scenes.map_server import read_map, write_map
from mjexplore.scenes.rectangles import cover_rectangles

WALL_HEIGHT = 3.0
WALL_GEOM_PREFIX = "wall_"
VISUAL_MESH_FILE = "building.stl"
PHYSICS_TIMESTEP = 0.005


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A scene before it is written: its grids, start pose and provenance.

    Attributes:
        name: Scene name (the MJCF model name).
        ground_truth: Ground-truth map (free, occupied, unknown) in the ``map`` frame.
        solid: Boolean grid (same shape as ``ground_truth``) of cells filled by walls in
            the MJCF; everything that is not free is solid.
        start: Start pose (x, y, yaw) of ``base_link`` in metres and radians.
        metadata: What made the scene (family, seed, size, source, ...), JSON-serialisable.
        wall_height: Wall height in metres.
        visual_mesh: Binary STL shown in the scene but neither collided with nor seen by
            the lidar (``map`` frame, metres, z up; written as ``VISUAL_MESH_FILE``), or
            None. Set by :mod:`mjexplore.scenes.mesh`.
    """

    name: str
    ground_truth: GridMap
    solid: np.ndarray
    start: tuple[float, float, float]
    metadata: dict[str, Any]
    wall_height: float = WALL_HEIGHT
    visual_mesh: bytes | None = None

    def wall_boxes(self) -> np.ndarray:
        """Wall boxes as (n, 4) [x0, y0, x1, y1] in metres (``map`` frame)."""
        rects = cover_rectangles(self.solid).astype(float)
        res = self.ground_truth.resolution
        ox, oy, _ = self.ground_truth.origin
        return np.stack([ox + rects[:, 1] * res, oy + rects[:, 0] * res,
                         ox + rects[:, 3] * res, oy + rects[:, 2] * res], axis=1)


# ---------------------------------------------------------------------- validation


def clearance(free: np.ndarray, resolution: float) -> np.ndarray:
    """Distance in metres from each free cell's centre to the nearest non-free cell's edge."""
    return ndimage.distance_transform_edt(free) * resolution - resolution / 2


def reachable_region(free: np.ndarray, resolution: float, seed_cell: tuple[int, int] | None,
                     robot_radius: float = TURTLEBOT3_WAFFLE.footprint_radius,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The robot's configuration space component and the free cells its footprint reaches.

    Args:
        free: Boolean free-cell grid.
        resolution: Cell side in metres.
        seed_cell: (row, col) inside the component to use; None picks the largest one.
        robot_radius: Footprint radius in metres.

    Returns:
        (cspace, reach): boolean grids. ``cspace``: cells where ``base_link`` fits, connected
        to the seed. ``reach``: free cells within the footprint of some ``cspace`` cell, with
        a tolerance so that the corners of rectangular rooms count as reached.
    """
    fits = clearance(free, resolution) > robot_radius
    labels, n = ndimage.label(fits, structure=np.ones((3, 3)))
    if n == 0:
        return fits, np.zeros_like(free)
    if seed_cell is None:
        label = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    else:
        label = int(labels[seed_cell])
        if label == 0:
            return np.zeros_like(free), np.zeros_like(free)
    cspace = labels == label
    tolerance = robot_radius * math.sqrt(2) + 2 * resolution
    near = ndimage.distance_transform_edt(~cspace) * resolution <= tolerance
    # Distances ignore walls: keep only the free region (4-connected) around the C-space,
    # so that free space behind a thin wall does not count as reached.
    regions, _ = ndimage.label(free)
    own = np.unique(regions[cspace])
    reach = free & near & np.isin(regions, own[own > 0])
    return cspace, reach


# Largest share of a generated layout's free area that may be unreachable pockets.
MAX_UNREACHABLE_SHARE = 0.1


def _unreachable(solid: np.ndarray, resolution: float) -> tuple[np.ndarray, int, int]:
    """(reach, free cells, free cells not reached) from the largest footprint region."""
    free = ~solid
    _, reach = reachable_region(free, resolution, None)
    return reach, int(free.sum()), int(free.sum() - reach.sum())


def unreachable_share(solid: np.ndarray, resolution: float) -> float:
    """Share of the free area the robot's footprint cannot reach from the largest region."""
    reach, free, lost = _unreachable(solid, resolution)
    return lost / max(free, 1) if reach.any() else 1.0


def fill_unreachable(solid: np.ndarray, resolution: float) -> np.ndarray:
    """Fills free pockets the robot's footprint cannot reach, so free space is one region.

    Raises:
        RuntimeError: more than ``MAX_UNREACHABLE_SHARE`` of the free area would be filled
            (a generator bug, not a user error).
    """
    reach, free, lost = _unreachable(solid, resolution)
    if not reach.any() or lost > MAX_UNREACHABLE_SHARE * free:
        raise RuntimeError(f"generated layout leaves {lost} of {free} free cells "
                           "unreachable")
    return ~reach


def pick_start(free: np.ndarray, resolution: float, rng: np.random.Generator,
               ) -> tuple[float, float, float]:
    """A start pose in the largest reachable region with generous clearance.

    Candidates are the cells with at least min(0.6 m, 80 % of the best clearance there),
    picked uniformly; the yaw is uniform. Coordinates are grid-relative (origin 0, 0).
    """
    cspace, _ = reachable_region(free, resolution, None)
    if not cspace.any():
        raise UserInputError("the map has no place where the robot fits: it needs free space "
                             f"wider than {2 * TURTLEBOT3_WAFFLE.footprint_radius:.2f} m.")
    dist = np.where(cspace, clearance(free, resolution), 0.0)
    rows, cols = np.nonzero(dist >= min(0.6, 0.8 * dist.max()))
    k = int(rng.integers(len(rows)))
    yaw = float(rng.uniform(-math.pi, math.pi))
    return (round((cols[k] + 0.5) * resolution, 4), round((rows[k] + 0.5) * resolution, 4),
            round(yaw, 4))


def check_start(grid: GridMap, start: tuple[float, float, float]) -> None:
    """Raises UserInputError unless the robot's footprint at ``start`` is in free space."""
    (x0, y0), (w, h) = grid.origin[:2], grid.size_m
    # In metres first: a far-off or non-finite start has no cell index.
    inside = x0 <= start[0] < x0 + w and y0 <= start[1] < y0 + h
    rc = grid.world_to_cell(np.array(start[:2])) if inside else None
    if rc is None or not grid.in_bounds(rc):
        raise UserInputError(f"start pose ({start[0]:.2f}, {start[1]:.2f}) is outside the map: "
                             "give a start inside it.")
    dist = clearance(grid.free, grid.resolution)[rc[0], rc[1]]
    if dist <= TURTLEBOT3_WAFFLE.footprint_radius:
        raise UserInputError(
            f"start pose ({start[0]:.2f}, {start[1]:.2f}) is {max(dist, 0):.2f} m from a wall or "
            f"unknown space; the robot needs {TURTLEBOT3_WAFFLE.footprint_radius:.2f} m: move the "
            "start into open free space.")


# ---------------------------------------------------------------------- MJCF


def _yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def build_spec(scene: Scene) -> mujoco.MjSpec:
    """Builds the MuJoCo model of a scene with ``MjSpec``: robot, floor, walls, light.

    Walls are boxes in geom group 0 (the only group the lidar sees); the robot's geoms are
    in groups 2 (visual) and 3 (collision).
    """
    spec = mujoco.MjSpec.from_file(str(ROBOT_XML))
    spec.modelname = scene.name
    spec.option.timestep = PHYSICS_TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    w, h = scene.ground_truth.size_m
    ox, oy, _ = scene.ground_truth.origin
    spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=300, height=300,
                     rgb1=[0.82, 0.82, 0.80], rgb2=[0.74, 0.74, 0.72])
    floor_mat = spec.add_material(name="floor", texrepeat=[w / 2, h / 2])
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.add_material(name="wall", rgba=[0.62, 0.64, 0.70, 1.0])
    world = spec.worldbody
    world.add_light(name="sun", pos=[ox + w / 2, oy + h / 2, 20.0], dir=[0, 0, -1],
                    type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, diffuse=[0.5, 0.5, 0.5],
                    castshadow=False)
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                   pos=[ox + w / 2, oy + h / 2, 0.0], size=[w / 2 + 1.0, h / 2 + 1.0, 0.05],
                   material="floor", group=1)
    hz = scene.wall_height / 2
    for i, (x0, y0, x1, y1) in enumerate(scene.wall_boxes()):
        world.add_geom(name=f"{WALL_GEOM_PREFIX}{i}", type=mujoco.mjtGeom.mjGEOM_BOX,
                       pos=[round((x0 + x1) / 2, 6), round((y0 + y1) / 2, 6), hz],
                       size=[round((x1 - x0) / 2, 6), round((y1 - y0) / 2, 6), hz],
                       material="wall", group=0)
    if scene.visual_mesh is not None:
        # Visual only: MuJoCo would collide with the mesh's convex hull (see scenes/mesh.py).
        spec.assets = {**spec.assets, VISUAL_MESH_FILE: scene.visual_mesh}
        spec.add_material(name="building", rgba=[0.85, 0.80, 0.72, 1.0])
        mesh = spec.add_mesh(name="building", file=VISUAL_MESH_FILE)
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # Open surfaces are fine.
        world.add_geom(name="building", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="building",
                       material="building", group=2, contype=0, conaffinity=0)
    base = spec.body("base_link")
    x, y, yaw = scene.start
    base.pos = [x, y, base.pos[2]]
    base.quat = _yaw_quat(yaw)
    return spec


# ---------------------------------------------------------------------- files


def preview_image(grid: GridMap, start: tuple[float, float, float] | None = None,
                  min_size: int = 600) -> np.ndarray:
    """BGR picture of a map: free white, occupied dark, unknown grey, north up; start in red."""
    img: np.ndarray = np.full(grid.shape, 150, np.uint8)
    img[grid.free] = 255
    img[grid.occupied] = 40
    scale = max(1, math.ceil(min_size / max(grid.shape)))
    img = cv2.resize(img[::-1], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if start is not None:
        px = scale / grid.resolution
        cx = (start[0] - grid.origin[0]) * px
        cy = img.shape[0] - (start[1] - grid.origin[1]) * px
        r = max(3, round(TURTLEBOT3_WAFFLE.footprint_radius * px))
        tip = (round(cx + 2 * r * math.cos(start[2])), round(cy - 2 * r * math.sin(start[2])))
        cv2.circle(img, (round(cx), round(cy)), r, (0, 0, 220), -1, cv2.LINE_AA)
        cv2.line(img, (round(cx), round(cy)), tip, (0, 0, 220), max(1, r // 3), cv2.LINE_AA)
    return img


def encode_png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def write_scene(scene: Scene, out_dir: str | os.PathLike) -> Path:
    """Writes a scene folder atomically (all files appear together or none do).

    Returns:
        Path of the written ``scene.xml``.
    """
    spec = build_spec(scene)
    spec.compile()  # Fails here, before anything is written, if the model is invalid.
    xml = spec.to_xml()
    boxes = scene.wall_boxes()
    meta = dict(scene.metadata)
    meta.update(name=scene.name, start=[round(v, 4) for v in scene.start],
                resolution=scene.ground_truth.resolution, wall_boxes=len(boxes),
                wall_height=scene.wall_height)
    out_dir = Path(out_dir)
    with atomic_directory(out_dir, "scene.json") as tmp:
        write_text_atomic(tmp / "scene.xml", xml)
        write_map(tmp / "map.yaml", scene.ground_truth)
        write_bytes_atomic(tmp / "preview.png",
                           encode_png(preview_image(scene.ground_truth, scene.start)))
        if scene.visual_mesh is not None:
            write_bytes_atomic(tmp / VISUAL_MESH_FILE, scene.visual_mesh)
        write_text_atomic(tmp / "scene.json", json.dumps(meta, indent=2, sort_keys=True) + "\n")
    return out_dir / "scene.xml"


@dataclasses.dataclass(frozen=True)
class SceneFiles:
    """Paths and facts of a scene on disk.

    Attributes:
        xml: The MJCF file.
        ground_truth: The ground-truth map, if the scene has one (None for a bare MJCF).
        start: Start pose (x, y, yaw) of ``base_link``, metres and radians.
        metadata: The contents of ``scene.json`` (empty for a bare MJCF).
        origin: Where the scene was given, when these files are a copy of it (a Ray worker
            runs a copy of the sweep's scene); None: ``xml`` itself.
    """

    xml: Path
    ground_truth: GridMap | None
    start: tuple[float, float, float]
    metadata: dict[str, Any]
    origin: str | None = None

    @property
    def source(self) -> str:
        """The scene as run records name it: where it was given."""
        return self.origin or str(self.xml)


# What ``--scene`` takes, for messages about what was given instead.
SCENE_FORMS = ("a canonical scene name (see 'mjexplore scene-gen --list'), a scene folder "
               "written by 'mjexplore scene-gen', its scene.xml (MJCF) or a map_server YAML")


def load_scene_files(path: str | os.PathLike) -> SceneFiles:
    """Opens a scene folder, its ``scene.xml``, or any MJCF that contains the robot.

    Raises:
        UserInputError: the path does not exist or is not a scene.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "scene.xml"
    if not path.is_file():
        raise UserInputError(f"scene {str(path)!r} does not exist: give a scene folder, an MJCF "
                             "file, or a canonical scene name (see 'mjexplore scene-gen --list').")
    folder = path.parent
    meta: dict[str, Any] = {}
    if (folder / "scene.json").is_file():
        try:
            loaded = json.loads((folder / "scene.json").read_text())
        except ValueError as exc:
            loaded = f"not valid JSON ({exc})"
        if not isinstance(loaded, dict):
            raise UserInputError(f"{str(folder / 'scene.json')!r} is damaged "
                                 f"({loaded if isinstance(loaded, str) else 'not a JSON object'}): "
                                 "regenerate the scene with 'mjexplore scene-gen'.")
        meta = loaded
    grid = read_map(folder / "map.yaml") if (folder / "map.yaml").is_file() else None
    if grid is not None and not grid.free.any():
        raise UserInputError(f"the map of scene {str(folder)!r} has no free cell (map.pgm is "
                             "all wall or unknown): regenerate the scene with 'mjexplore "
                             "scene-gen', or fix map.pgm (free cells white).")
    if "start" in meta:
        # (x, y, yaw), as 'mjexplore scene-gen' writes it.
        start = cast("tuple[float, float, float]", tuple(float(v) for v in meta["start"]))
    else:
        start = _start_from_mjcf(path)
    return SceneFiles(path, grid, start, meta)


def _start_from_mjcf(path: Path) -> tuple[float, float, float]:
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        if path.suffix.lower() != ".xml":
            raise UserInputError(
                f"{str(path)!r} is not a scene (MuJoCo cannot read it as MJCF: {exc}): a scene "
                f"is {SCENE_FORMS}; 'mjexplore scene-gen --from-map' imports a map image and "
                "'--from-mesh' a 3D model.") from None
        raise UserInputError(f"MJCF {str(path)!r} could not be parsed ({exc}); fix the XML or "
                             "regenerate the scene with 'mjexplore scene-gen'.") from None
    try:
        base = spec.body("base_link")
    except Exception:  # noqa: BLE001 - MjSpec raises a bare error type for missing names.
        base = None
    if base is None:
        raise UserInputError(f"MJCF {str(path)!r} has no body 'base_link': it must contain the "
                             "robot (assets/turtlebot3_waffle/robot.xml).")
    qw, _, _, qz = base.quat
    return float(base.pos[0]), float(base.pos[1]), 2 * math.atan2(qz, qw)


def ground_truth_from_solid(solid: np.ndarray, resolution: float) -> GridMap:
    data = np.where(solid, OCCUPIED, FREE).astype(np.int8)
    return GridMap(data, resolution, (0.0, 0.0, 0.0))


__all__ = [
    "SCENE_FORMS",
    "Scene",
    "SceneFiles",
    "build_spec",
    "check_start",
    "clearance",
    "fill_unreachable",
    "ground_truth_from_solid",
    "load_scene_files",
    "pick_start",
    "reachable_region",
    "write_scene",
]
