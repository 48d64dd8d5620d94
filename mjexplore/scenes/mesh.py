"""Mesh worlds: scenes from 3D building models, and scenes written out as meshes.

Import (:func:`scene_from_mesh`). A building model (GLB/glTF, OBJ, STL, PLY, OFF) is read
with trimesh, its geometries merged with their scene-graph transforms, converted to
metres (``scale``: metres per file unit) and to z up (REP-103), and shifted so that its
floor is at z = 0. It is then cut at the lidar's height above the floor (0.132 m for the
Turtlebot3 Waffle: ``base_link`` 0.010 m above the floor plus the ``base_scan`` offset):

- walls: every cell of the ground-truth grid that the cross-section's lines pass through,
  so that walls are unbroken 8-connected chains however thin (a scan's walls are single
  surfaces), and the cells inside the outlines of solids (closed loops running
  counter-clockwise around the solid, over the solid's own underside rather than a
  floor: see :func:`wall_cells`);
- floor: the cells under upward-facing surfaces near the floor level; the building's
  inside is the floor and the walls with every hole they enclose filled (gaps between a
  scan's floor and its walls, holes in the floor; a walls-only model's rooms);
- free: the inside cells that are not wall and that the robot's footprint reaches from
  the start (:func:`mjexplore.scenes.scene.reachable_region`, as generated scenes); the
  rest of the inside (the hollow of thick walls, closed rooms, niches too narrow for the
  robot) is occupied, and cells outside the building are unknown.

The MJCF is built as for every other scene: the cells that are not free become merged wall
boxes (geom group 0, which both physics and the lidar use), and the model itself is added
as a visual-only mesh (``building.stl`` beside ``scene.xml``: group 2, contype and
conaffinity 0) so that renders show the building. Why boxes and not the mesh for
collision and rays (measured with the 10 x 8 m test building of ``tests/test_mesh.py``,
MuJoCo 4.0, 2 CPU cores):

- MuJoCo collides with a mesh geom through its convex hull, which fills every room: the
  robot at the start of the test building, with the building as a collision mesh, has 8
  contacts with it at once (with box walls: only its wheels and casters on the floor);
- ``mj_multiRay`` does hit a mesh's triangles (ranges equal to the boxes' within 1e-6 m),
  but the lidar's per-tile ray models (:mod:`mjexplore.sim.lidar`) take primitives only,
  so a mesh in group 0 sends every scan to the whole model: a 360-beam scan costs 0.9 ms
  against the 166-triangle building and 7.2 ms against 170 k triangles (a scan's size),
  against 0.17 ms for the box walls of a tile;
- boxes from the ground-truth cells make the lidar, physics and the ground truth agree
  cell for cell, the property every metric relies on; they differ from the mesh by less
  than a cell (0.05 m) at the lidar's height.

The visual mesh is the model below 1.2 m above the floor (the height at which floor plans
cut a building, so views from above show the rooms instead of a roof) inside the map's
bounds, less the floor's own faces (the MJCF has a floor plane at z = 0); with more than
100,000 triangles it is simplified by vertex clustering (vertices snapped to a grid as
fine as the budget allows and merged; trimesh's quadric decimation needs the
``fast-simplification`` package, which is not a dependency).

Up axis: glTF is y-up by specification, and OBJ files are y-up in practice (Blender's,
Maya's and most scanners' exports), so GLB, glTF and OBJ are read as y-up; STL, PLY and
OFF (CAD and 3D printing) as z-up. A y-up file is turned to z-up by +90 degrees about x:
(x, y, z) -> (x, -z, y), as Blender's glTF importer does. The floor is the level of
upward-facing surfaces with the most area within 0.5 m of the model's lowest point (a slab
or foundation may lie below the floor), or that point for walls without a floor;
``floor_z`` overrides it, e.g. to pick an upper storey.

Export (:func:`export_scene_mesh`): any scene's wall boxes (from its MJCF) extruded to
their height and its floor as a 0.1 m slab under z = 0, in metres, in the map frame. Files
are written in the up axis they are read with: GLB (two nodes, ``walls`` and ``floor``)
y-up, (x, y, z) -> (x, z, -y); OBJ y-up; STL and PLY z-up. So an exported scene imports
back unchanged (``--from-mesh``) and opens upright in Blender, Foxglove's 3D panel or
Gazebo (``<mesh><uri>`` of a GLB).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import os
from pathlib import Path
from typing import Any, cast

import mujoco
import numba
import numpy as np
import trimesh
from scipy import ndimage, sparse, spatial
from scipy.sparse import csgraph

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import check_output_file, write_bytes_atomic
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.robot import ROBOT_XML, TURTLEBOT3_WAFFLE
from mjexplore.scenes.scene import (
    WALL_GEOM_PREFIX,
    WALL_HEIGHT,
    Scene,
    check_start,
    clearance,
    pick_start,
    reachable_region,
)

log = logging.getLogger(__name__)

# Default up axis per file suffix (see the module docstring).
MESH_FORMATS = {".glb": "y", ".gltf": "y", ".obj": "y", ".stl": "z", ".ply": "z", ".off": "z"}
EXPORT_FORMATS = (".glb", ".obj", ".stl", ".ply")
# Metres per file unit.
MESH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
# A building's horizontal extent outside this range (metres) means a wrong unit.
MIN_FOOTPRINT_M = 2.0
MAX_FOOTPRINT_M = 500.0
MAX_GRID_CELLS = 25_000_000
VISUAL_CUT_HEIGHT = 1.2
VISUAL_MAX_FACES = 100_000
FLOOR_NORMAL_Z = 0.94  # Faces within 20 degrees of horizontal, facing up, can be floor.
FLOOR_BIN_M = 0.01
FLOOR_SEARCH_M = 0.5
FLOOR_SLAB_M = 0.1
GRID_MARGIN_CELLS = 2
# y-up to z-up: +90 degrees about x.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@functools.cache
def lidar_height() -> float:
    """Height of ``base_scan`` above the floor in metres when the robot stands on it."""
    base = mujoco.MjSpec.from_file(str(ROBOT_XML)).body("base_link")
    return float(base.pos[2]) + TURTLEBOT3_WAFFLE.scan_offset[2]


@dataclasses.dataclass(frozen=True, kw_only=True)
class MeshImportConfig:
    """How a building model is read and cut.

    Attributes:
        scale: Metres per file unit (see ``MESH_UNITS``).
        up_axis: 'y' or 'z', the file's up axis; None: by suffix (``MESH_FORMATS``).
        floor_z: Floor height in metres after scaling and turning z-up; None: found.
        height: Height above the floor of the cut giving walls and ground truth, metres;
            None: the lidar's height.
        resolution: Ground-truth cell side in metres.
    """

    scale: float = 1.0
    up_axis: str | None = None
    floor_z: float | None = None
    height: float | None = None
    resolution: float = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise UserInputError(f"mesh scale {self.scale} must be a positive number of metres "
                                 "per file unit (or give --mesh-units).")
        if self.up_axis not in (None, "y", "z"):
            raise UserInputError(f"up axis {self.up_axis!r} must be 'y' or 'z'.")
        if not 0.01 <= self.resolution <= 0.5:
            raise UserInputError(f"resolution {self.resolution} m is out of range: use 0.01 to "
                                 "0.5 m.")
        if self.height is not None and not 0 < self.height < WALL_HEIGHT:
            raise UserInputError(f"height {self.height} m must be above the floor and below "
                                 f"{WALL_HEIGHT:g} m (the lidar is at about 0.13 m).")
        if self.floor_z is not None and not math.isfinite(self.floor_z):
            raise UserInputError(f"floor height {self.floor_z} must be a number of metres.")


def units_scale(units: str) -> float:
    """Metres per file unit for a unit name ('m', 'cm', 'mm', 'in', 'ft')."""
    try:
        return MESH_UNITS[units]
    except KeyError:
        raise UserInputError(f"unknown mesh unit {units!r}: use one of {', '.join(MESH_UNITS)}, "
                             "or --mesh-scale METRES_PER_UNIT.") from None


# ---------------------------------------------------------------------- reading


def load_mesh(path: str | os.PathLike, scale: float = 1.0, up_axis: str | None = None,
              ) -> trimesh.Trimesh:
    """Reads a mesh file as one triangle mesh in metres, z up (file's own origin).

    Every geometry of the file's scene graph is placed with its transform; points, lines and
    textures are ignored. Faces with non-finite or repeated vertices are dropped.

    Raises:
        UserInputError: missing file, unsupported format, unreadable or empty mesh.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise UserInputError(f"{str(path)!r} is not a mesh format mjexplore reads: give a "
                             f"{', '.join(s[1:].upper() for s in MESH_FORMATS)} file.")
    if not path.is_file():
        raise UserInputError(f"mesh {str(path)!r} does not exist.")
    try:
        # force="scene" makes it a Scene (trimesh types the result as any Geometry).
        loaded = cast(trimesh.Scene, trimesh.load(str(path), force="scene", process=False))
        parts = []
        for node in loaded.graph.nodes_geometry:
            transform, name = loaded.graph[node]
            geometry = loaded.geometry[name]
            if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
                parts.append((trimesh.transform_points(geometry.vertices, transform),
                              np.asarray(geometry.faces, dtype=np.int64)))
    except Exception as exc:  # noqa: BLE001 - trimesh's readers raise many error types.
        raise UserInputError(f"mesh {str(path)!r} could not be read as {suffix[1:].upper()} "
                             f"({type(exc).__name__}: {str(exc)[:200]}); check that the file is "
                             "complete and exported as triangles.") from None
    offsets = np.cumsum([0] + [len(v) for v, _ in parts])
    vertices = np.concatenate([v for v, _ in parts]) if parts else np.zeros((0, 3))
    faces = (np.concatenate([f + o for (_, f), o in zip(parts, offsets)]) if parts
             else np.zeros((0, 3), np.int64))
    good = np.all(np.isfinite(vertices), axis=1)
    faces = faces[good[faces].all(axis=1)]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
                  & (faces[:, 0] != faces[:, 2])]
    vertices = vertices * scale
    if (up_axis or MESH_FORMATS[suffix]) == "y":
        vertices = vertices @ Y_UP_TO_Z_UP.T
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.remove_unreferenced_vertices()
    if len(faces) == 0 or not mesh.area > 0:
        raise UserInputError(f"mesh {str(path)!r} holds no triangles with area (empty, or only "
                             "points or lines): export the building as a triangle mesh.")
    return mesh


def check_scale(mesh: trimesh.Trimesh, path: str | os.PathLike, scale: float) -> None:
    """Raises UserInputError unless the mesh's horizontal extent looks like a building's."""
    extent = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    if MIN_FOOTPRINT_M <= extent <= MAX_FOOTPRINT_M:
        return
    file_extent = extent / scale
    fits = [u for u, m in MESH_UNITS.items()
            if MIN_FOOTPRINT_M <= file_extent * m <= MAX_FOOTPRINT_M]
    unit_names = {"m": "metres", "cm": "centimetres", "mm": "millimetres", "in": "inches",
                  "ft": "feet"}
    if fits:
        best = min(fits, key=lambda u: abs(math.log(file_extent * MESH_UNITS[u] / 20.0)))
        hint = f"looks like {unit_names[best]}, pass --mesh-units {best}"
    else:
        hint = "pass --mesh-scale METRES_PER_UNIT"
    raise UserInputError(
        f"mesh {Path(path).name!r} is {extent:.4g} m across at {scale:g} m per file unit, not "
        f"a building ({MIN_FOOTPRINT_M:g} to {MAX_FOOTPRINT_M:g} m): {hint} (or remove a "
        "large ground plane from the model).")


def floor_level(mesh: trimesh.Trimesh) -> float:
    """The floor's height in metres: the level (1 cm bins) of upward-facing surfaces with
    the most area within ``FLOOR_SEARCH_M`` of the model's lowest point, or that point if
    none faces up there (walls without a floor)."""
    bottom = float(mesh.vertices[:, 2].min())
    z = mesh.triangles_center[:, 2]
    up = (mesh.face_normals[:, 2] >= FLOOR_NORMAL_Z) & (z <= bottom + FLOOR_SEARCH_M)
    if not up.any():
        return bottom
    _, inverse = np.unique(np.floor(z[up] / FLOOR_BIN_M), return_inverse=True)
    area = np.bincount(inverse, weights=mesh.area_faces[up])
    return float(np.median(z[up][inverse == int(np.argmax(area))]))


# ---------------------------------------------------------------------- rasterising


def wall_segments(mesh: trimesh.Trimesh, z: float,
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cross-section at height ``z``.

    A solid's section is a set of closed loops that run counter-clockwise around the solid
    (its faces' normals on their right) and clockwise around its holes. Loops of
    zero-thickness surfaces (a scan's walls, a room drawn as planes) enclose no solid: their
    normals point inwards, or every which way.

    Returns:
        (segments, normals, part): segments (n, 2, 2) [[x0, y0], [x1, y1]] in metres,
        oriented with their face's normal on the right; the unit horizontal normals (n, 2)
        of those faces (zero if horizontal); and the solid outline each belongs to (a
        connected set of segments entering and leaving every end as often, enclosing a
        positive area), -1 for other lines.
    """
    lines, faces = trimesh.intersections.mesh_plane(mesh, [0.0, 0.0, 1.0], [0.0, 0.0, z],
                                                    return_faces=True)
    segments = lines[:, :, :2]
    normals = mesh.face_normals[faces, :2]
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 1e-9)
    n = len(segments)
    if n == 0:
        return segments, normals, np.zeros(0, np.int64)
    d = segments[:, 1] - segments[:, 0]
    flip = d[:, 1] * normals[:, 0] - d[:, 0] * normals[:, 1] < 0
    segments[flip] = segments[flip][:, ::-1]
    # Ends of neighbouring segments are computed apart: join ends within a micrometre.
    ends = segments.reshape(-1, 2)
    pairs = spatial.cKDTree(ends).query_pairs(1e-6, output_type="ndarray")
    same = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                             shape=(2 * n, 2 * n))
    _, vertex = csgraph.connected_components(same, directed=False)
    links = sparse.coo_matrix((np.ones(n), (np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2))),
                              shape=(2 * n, 2 * n))
    _, outline = csgraph.connected_components(same + links, directed=False)
    part = outline[0::2]
    leaving = np.bincount(vertex[0::2], minlength=vertex.max() + 1)
    entering = np.bincount(vertex[1::2], minlength=vertex.max() + 1)
    unbalanced = np.zeros(part.max() + 1, dtype=bool)
    np.logical_or.at(unbalanced, outline, (leaving != entering)[vertex])
    np.logical_or.at(unbalanced, part, ~normals.any(axis=1))
    a, b = segments[:, 0], segments[:, 1]
    area = np.bincount(part, weights=(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]) / 2)
    solid = ~unbalanced & (area > 0)
    return segments, normals, np.where(solid[part], part, -1)


def rasterise_segments(segments: np.ndarray, normals: np.ndarray, grid_origin: np.ndarray,
                       resolution: float, shape: tuple[int, int]) -> np.ndarray:
    """Cells (boolean grid) that line segments pass through.

    Points are taken along each segment at most half a cell apart, so consecutive points
    fall in the same or 8-adjacent cells and a closed outline stays closed. Each point is
    moved a thousandth of a cell against its face's normal (into a solid wall), and the
    ends a thousandth of a cell inwards, so that a face lying on a cell edge marks the cell
    inside the wall only.

    Args:
        segments: (n, 2, 2) segments in metres (``map`` frame).
        normals: (n, 2) unit normals pointing out of the walls (zero: no preferred side).
        grid_origin: (x, y) of the lower-left corner of cell (0, 0), metres.
        resolution: Cell side in metres.
        shape: (rows, cols) of the grid.
    """
    grid = np.zeros(shape, dtype=bool)
    if len(segments) == 0:
        return grid
    nudge = 1e-3
    a = (segments[:, 0] - grid_origin) / resolution
    d = (segments[:, 1] - grid_origin) / resolution - a
    length = np.linalg.norm(d, axis=1)
    unit = np.divide(d, length[:, None], out=np.zeros_like(d), where=length[:, None] > 0)
    count = np.ceil(length / 0.5).astype(np.int64) + 1
    seg = np.repeat(np.arange(len(a)), count)
    first = np.cumsum(count) - count
    step = (np.arange(len(seg)) - first[seg]) / np.maximum(count[seg] - 1, 1)
    usable = np.maximum(length - 2 * nudge, 0.0)
    along = np.where(length[seg] > 2 * nudge, nudge + step * usable[seg], length[seg] / 2)
    points = a[seg] + unit[seg] * along[:, None] - normals[seg] * nudge
    cols = np.clip(np.floor(points[:, 0]).astype(np.int64), 0, shape[1] - 1)
    rows = np.clip(np.floor(points[:, 1]).astype(np.int64), 0, shape[0] - 1)
    grid[rows, cols] = True
    return grid


@numba.njit(cache=True)
def _fill_triangles(tri: np.ndarray, grid: np.ndarray) -> None:
    """Sets the cells whose centres lie in (or on) any triangle (n, 3, 2), in cell units."""
    rows, cols = grid.shape
    for i in range(tri.shape[0]):
        x0, y0 = tri[i, 0, 0], tri[i, 0, 1]
        x1, y1 = tri[i, 1, 0], tri[i, 1, 1]
        x2, y2 = tri[i, 2, 0], tri[i, 2, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        s = 1.0 if area > 0 else -1.0
        c0 = max(int(math.ceil(min(x0, x1, x2) - 0.5)), 0)
        c1 = min(int(math.floor(max(x0, x1, x2) - 0.5)), cols - 1)
        r0 = max(int(math.ceil(min(y0, y1, y2) - 0.5)), 0)
        r1 = min(int(math.floor(max(y0, y1, y2) - 0.5)), rows - 1)
        for r in range(r0, r1 + 1):
            py = r + 0.5
            for c in range(c0, c1 + 1):
                px = c + 0.5
                e0 = s * ((x1 - x0) * (py - y0) - (y1 - y0) * (px - x0))
                e1 = s * ((x2 - x1) * (py - y1) - (y2 - y1) * (px - x1))
                e2 = s * ((x0 - x2) * (py - y2) - (y0 - y2) * (px - x2))
                if e0 >= -1e-9 and e1 >= -1e-9 and e2 >= -1e-9:
                    grid[r, c] = True


def rasterise_triangles(triangles: np.ndarray, grid_origin: np.ndarray, resolution: float,
                        shape: tuple[int, int]) -> np.ndarray:
    """Cells (boolean grid) whose centres lie in any of the triangles (n, 3, 2), metres."""
    grid = np.zeros(shape, dtype=bool)
    if len(triangles):
        _fill_triangles(np.ascontiguousarray((triangles - grid_origin) / resolution,
                                             dtype=np.float64), grid)
    return grid


@numba.njit(cache=True)
def _fill_outlines(seg: np.ndarray, starts: np.ndarray, keep: np.ndarray, grid: np.ndarray,
                   inner: np.ndarray) -> None:
    """Even-odd fill of groups of closed outlines, one group at a time (groups may overlap).

    Args:
        seg: (n, 2, 2) segments in cell units, grouped: group k is
            ``seg[starts[k]:starts[k + 1]]``.
        starts: (k + 1,) group bounds.
        keep: (k,) whether to set the cells of each group in ``grid``.
        grid: Boolean grid; the cells whose centres lie inside kept groups are set.
        inner: (k, 2) int output: a (row, col) inside each group, (-1, -1) if none.
    """
    rows, cols = grid.shape
    xs = np.empty(seg.shape[0])
    for k in range(len(starts) - 1):
        s0, s1 = starts[k], starts[k + 1]
        inner[k, 0] = -1
        inner[k, 1] = -1
        r0 = max(int(math.ceil(seg[s0:s1, :, 1].min() - 0.5)), 0)
        r1 = min(int(math.floor(seg[s0:s1, :, 1].max() - 0.5)), rows - 1)
        for r in range(r0, r1 + 1):
            yc = r + 0.5
            n = 0
            for i in range(s0, s1):
                ya, yb = seg[i, 0, 1], seg[i, 1, 1]
                if (ya <= yc) != (yb <= yc):
                    xa, xb = seg[i, 0, 0], seg[i, 1, 0]
                    xs[n] = xa + (yc - ya) * (xb - xa) / (yb - ya)
                    n += 1
            crossings = np.sort(xs[:n])
            for j in range(0, n - 1, 2):
                c0 = max(int(math.ceil(crossings[j] - 0.5)), 0)
                c1 = min(int(math.floor(crossings[j + 1] - 0.5)), cols - 1)
                if c1 >= c0 and inner[k, 0] < 0:
                    inner[k, 0] = r
                    inner[k, 1] = (c0 + c1) // 2
                if keep[k]:
                    for c in range(c0, c1 + 1):
                        grid[r, c] = True


@numba.njit(cache=True)
def _solid_below(points: np.ndarray, tri: np.ndarray, normal_z: np.ndarray,
                 tolerance: float) -> np.ndarray:
    """Whether the nearest surface straight below each point (k, 3) is seen from behind
    (the point is inside a solid), among triangles (m, 3, 3) with normals' z ``normal_z``;
    of surfaces within ``tolerance`` of the nearest, any seen from behind wins (a wall
    standing on a floor)."""
    out = np.zeros(points.shape[0], dtype=np.bool_)
    for k in range(points.shape[0]):
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        best = -np.inf
        behind = False
        for i in range(tri.shape[0]):
            x0, y0, z0 = tri[i, 0, 0], tri[i, 0, 1], tri[i, 0, 2]
            x1, y1, z1 = tri[i, 1, 0], tri[i, 1, 1], tri[i, 1, 2]
            x2, y2, z2 = tri[i, 2, 0], tri[i, 2, 1], tri[i, 2, 2]
            if (px < min(x0, x1, x2) or px > max(x0, x1, x2) or py < min(y0, y1, y2)
                    or py > max(y0, y1, y2) or min(z0, z1, z2) > pz):
                continue
            det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if abs(det) < 1e-12:
                continue
            u = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / det
            v = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / det
            if u < 0 or v < 0 or u + v > 1:
                continue
            z = z0 + u * (z1 - z0) + v * (z2 - z0)
            if z > pz:
                continue
            back = normal_z[i] < 0
            if z > best + tolerance:
                best, behind = z, back
            elif z >= best - tolerance:
                behind = behind or back
                best = max(best, z)
        out[k] = behind
    return out


def wall_cells(mesh: trimesh.Trimesh, z: float,
               section: tuple[np.ndarray, np.ndarray, np.ndarray], grid_origin: np.ndarray,
               resolution: float, shape: tuple[int, int]) -> np.ndarray:
    """Wall cells (boolean grid) of the mesh's cross-section at height ``z``: the cells its
    lines pass through, and the cells inside solid outlines under which the nearest
    surface is the solid's own underside (not a floor: the outer walls of a building drawn
    as planes facing out also run counter-clockwise).

    Args:
        mesh: The mesh, metres, z up.
        z: Height of the cut in metres.
        section: ``wall_segments(mesh, z)``.
        grid_origin: (x, y) of the lower-left corner of cell (0, 0), metres.
        resolution: Cell side in metres.
        shape: (rows, cols) of the grid.
    """
    segments, normals, part = section
    grid = rasterise_segments(segments, normals, grid_origin, resolution, shape)
    closed = part >= 0
    if not closed.any():
        return grid
    order = np.argsort(part[closed], kind="stable")
    _, starts = np.unique(part[closed][order], return_index=True)
    seg = np.ascontiguousarray((segments[closed][order] - grid_origin) / resolution)
    starts = np.append(starts, closed.sum()).astype(np.int64)
    inner = np.empty((len(starts) - 1, 2), dtype=np.int64)
    keep = np.zeros(len(inner), dtype=bool)
    _fill_outlines(seg, starts, keep, grid, inner)
    has = inner[:, 0] >= 0
    points = np.column_stack([grid_origin + (inner[has, ::-1] + 0.5) * resolution,
                              np.full(has.sum(), z)])
    flat = np.abs(mesh.face_normals[:, 2]) > 1e-6
    keep[has] = _solid_below(points, np.ascontiguousarray(mesh.triangles[flat]),
                             np.ascontiguousarray(mesh.face_normals[flat, 2]), 1e-3)
    _fill_outlines(seg, starts, keep, grid, inner)
    return grid


# ---------------------------------------------------------------------- import


def scene_from_mesh(path: str | os.PathLike, config: MeshImportConfig | None = None,
                    start: tuple[float, float, float] | None = None, seed: int = 0,
                    name: str | None = None) -> Scene:
    """Imports a building model as a scene (see the module docstring).

    Args:
        path: GLB, glTF, OBJ, STL, PLY or OFF file.
        config: Units, up axis, floor and cut height, resolution.
        start: Start pose (x, y, yaw) in the ``map`` frame (the model's x, y in metres);
            None picks one with clearance, drawn with ``seed``.
        seed: Seed for the start pose.
        name: Scene name; defaults to the file's stem.

    Raises:
        UserInputError: unreadable or empty mesh, a size that is not a building's (wrong
            units), nothing at the cut height, no floor inside walls, or a bad start.
    """
    config = config or MeshImportConfig()
    path = Path(path)
    mesh = load_mesh(path, config.scale, config.up_axis)
    check_scale(mesh, path, config.scale)
    up = config.up_axis or MESH_FORMATS[path.suffix.lower()]
    floor_z = floor_level(mesh) if config.floor_z is None else config.floor_z
    mesh.vertices[:, 2] -= floor_z
    height = lidar_height() if config.height is None else config.height
    section = wall_segments(mesh, height)
    segments = section[0]
    if len(segments) == 0:
        size = np.ptp(mesh.vertices, axis=0)
        raise UserInputError(
            f"mesh {path.name!r} has nothing at {height:.3f} m above its floor (floor at "
            f"z = {floor_z:.3f} m; the model is {size[0]:.3g} x {size[1]:.3g} m and "
            f"{size[2]:.3g} m tall, read as {up}-up): check --up-axis, give the floor with "
            "--floor-z, or the cut height with --height.")
    res = config.resolution
    lo = np.floor(segments.reshape(-1, 2).min(axis=0) / res) - GRID_MARGIN_CELLS
    hi = np.ceil(segments.reshape(-1, 2).max(axis=0) / res) + GRID_MARGIN_CELLS
    shape = (int(hi[1] - lo[1]), int(hi[0] - lo[0]))
    if shape[0] * shape[1] > MAX_GRID_CELLS:
        raise UserInputError(f"the map of {path.name!r} would have {shape[1]} x {shape[0]} "
                             f"cells at {res} m: pass a coarser --resolution (e.g. "
                             f"{res * 2:g}).")
    origin = np.round(lo * res, 9)
    x0, y0 = float(origin[0]), float(origin[1])
    wall = wall_cells(mesh, height, section, origin, res, shape)
    floor_faces = ((mesh.face_normals[:, 2] >= FLOOR_NORMAL_Z)
                   & (np.abs(mesh.triangles_center[:, 2]) < min(height, 0.05)))
    floor = rasterise_triangles(mesh.triangles[floor_faces][:, :, :2], origin, res, shape)
    inside = ndimage.binary_fill_holes(floor | wall)
    inside[[0, -1], :] = False
    inside[:, [0, -1]] = False
    candidate = inside & ~wall
    if not candidate.any():
        raise UserInputError(
            f"mesh {path.name!r} has no floor area inside walls at {height:.3f} m above its "
            f"floor (z = {floor_z:.3f} m): the model needs a floor (upward-facing surface at "
            "the floor level) or rooms enclosed by walls; check --up-axis and --floor-z.")
    grid = GridMap(np.where(candidate, FREE, OCCUPIED).astype(np.int8), res, (x0, y0, 0.0))
    if start is None:
        sx, sy, yaw = pick_start(candidate, res, np.random.default_rng(seed))
        start = (round(x0 + float(sx), 4), round(y0 + float(sy), 4), yaw)
    check_start(grid, start)
    seed_cell = tuple(grid.world_to_cell(np.array(start[:2])))
    cspace, free = reachable_region(candidate, res, seed_cell)
    data = np.full(shape, UNKNOWN, np.int8)
    data[inside | wall] = OCCUPIED
    data[free] = FREE
    ground_truth = GridMap(data, res, grid.origin)
    # Rooms the robot would fit in but cannot reach (closed doors): walls in the scene.
    fits = clearance(candidate, res) > TURTLEBOT3_WAFFLE.footprint_radius
    regions, _ = ndimage.label(candidate & ~free)
    lost_rooms = (regions > 0) & np.isin(regions, np.unique(regions[fits & ~cspace]))
    lost_m2 = float(lost_rooms.sum() * res * res)
    if lost_m2 > 0:
        log.warning("%s: %.1f m2 of floor is in rooms the robot cannot reach from the start "
                    "(closed doors or gaps narrower than the robot); they are walls in the "
                    "scene.", path.name, lost_m2)
    # The floor's own faces would flicker against the MJCF's floor plane at z = 0.
    visual = visual_mesh(trimesh.Trimesh(mesh.vertices, mesh.faces[~floor_faces],
                                         process=False), ground_truth)
    metadata: dict[str, Any] = {
        "source": "mesh",
        "mesh": path.name,
        "mesh_scale": config.scale,
        "up_axis": up,
        "floor_z": round(floor_z, 4),
        "cut_height": round(height, 4),
        "mesh_faces": int(len(mesh.faces)),
        "visual_faces": 0 if visual is None else int(len(visual.faces)),
        "reachable_free_fraction": round(float(free.sum() / candidate.sum()), 4),
        "unreachable_room_area_m2": round(lost_m2, 2),
    }
    return Scene(name=name or path.stem, ground_truth=ground_truth, solid=~free,
                 start=(start[0], start[1], start[2]), metadata=metadata,
                 # An STL export is bytes (trimesh types it as any export).
                 visual_mesh=None if visual is None else cast(bytes, visual.export(
                     file_type="stl")))


def visual_mesh(mesh: trimesh.Trimesh, grid: GridMap) -> trimesh.Trimesh | None:
    """The part of a floor-levelled mesh shown in the scene: below ``VISUAL_CUT_HEIGHT``,
    inside the map's bounds, at most ``VISUAL_MAX_FACES`` triangles (None if nothing)."""
    (x0, y0, _), (w, h) = grid.origin, grid.size_m
    planes = [([0, 0, -1], [0, 0, VISUAL_CUT_HEIGHT]), ([1, 0, 0], [x0, 0, 0]),
              ([-1, 0, 0], [x0 + w, 0, 0]), ([0, 1, 0], [0, y0, 0]), ([0, -1, 0], [0, y0 + h, 0])]
    vertices, faces = mesh.vertices, mesh.faces
    for normal, origin in planes:
        vertices, faces, _ = trimesh.intersections.slice_faces_plane(
            vertices, faces, np.array(normal, float), np.array(origin, float))
        if len(faces) == 0:
            return None
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) > VISUAL_MAX_FACES:
        mesh = cluster_simplify(mesh, VISUAL_MAX_FACES)
    return mesh


def cluster_simplify(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Vertex clustering: snaps vertices to the finest cubic grid (pitch doubled from a
    guess) that leaves at most ``max_faces`` distinct non-degenerate triangles."""
    pitch = math.sqrt(mesh.area / max_faces) / 2
    while True:
        keys = np.floor(mesh.vertices / pitch).astype(np.int64)
        _, index, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        faces = inverse.reshape(-1)[mesh.faces]
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
                      & (faces[:, 0] != faces[:, 2])]
        _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
        faces = faces[np.sort(first)]
        if len(faces) <= max_faces:
            log.info("visual mesh simplified from %d to %d triangles (%.3f m clusters)",
                     len(mesh.faces), len(faces), pitch)
            return trimesh.Trimesh(mesh.vertices[index], faces, process=False)
        pitch *= 2


# ---------------------------------------------------------------------- export


def _boxes(centres: np.ndarray, half: np.ndarray, rotations: np.ndarray,
           ) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward-wound faces of boxes (centres (n, 3), half sizes (n, 3),
    rotation matrices (n, 3, 3)), all in one array each."""
    unit = trimesh.creation.box(extents=[2.0, 2.0, 2.0])
    corners = np.asarray(unit.vertices)  # (8, 3) at +-1
    vertices = np.einsum("nij,nkj->nki", rotations, corners[None] * half[:, None, :])
    vertices = (vertices + centres[:, None, :]).reshape(-1, 3)
    faces = (np.asarray(unit.faces)[None] + 8 * np.arange(len(centres))[:, None, None])
    return vertices, faces.reshape(-1, 3)


def scene_meshes(xml: str | os.PathLike) -> dict[str, trimesh.Trimesh]:
    """The walls (boxes named ``wall_*``) and floor (planes, as slabs under them) of a
    scene's MJCF, z up, metres, ``map`` frame.

    Raises:
        UserInputError: the MJCF cannot be loaded or holds no walls.
    """
    try:
        model = mujoco.MjModel.from_xml_path(str(xml))
    except ValueError as exc:
        raise UserInputError(f"MJCF {str(xml)!r} could not be loaded ({exc}); regenerate the "
                             "scene with 'mjexplore scene-gen'.") from None
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ids = np.arange(model.ngeom)
    static = model.geom_bodyid == 0
    names = np.array([model.geom(int(i)).name for i in ids])
    walls = (static & (model.geom_type == mujoco.mjtGeom.mjGEOM_BOX)
             & np.char.startswith(names, WALL_GEOM_PREFIX))
    if not walls.any():
        raise UserInputError(f"MJCF {str(xml)!r} has no wall boxes ('{WALL_GEOM_PREFIX}*' "
                             "geoms): export scenes made by 'mjexplore scene-gen'.")
    xmat = data.geom_xmat.reshape(-1, 3, 3)
    out = {"walls": trimesh.Trimesh(*_boxes(data.geom_xpos[walls], model.geom_size[walls],
                                            xmat[walls]), process=False)}
    planes = static & (model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
    if planes.any():
        half = model.geom_size[planes].copy()
        half[:, 2] = FLOOR_SLAB_M / 2
        centres = data.geom_xpos[planes] - xmat[planes][:, :, 2] * FLOOR_SLAB_M / 2
        out["floor"] = trimesh.Trimesh(*_boxes(centres, half, xmat[planes]), process=False)
    return out


def check_export_path(out: str | os.PathLike) -> Path:
    """Raises UserInputError unless ``out`` names a mesh file :func:`export_scene_mesh`
    can write."""
    out = Path(out)
    if out.suffix.lower() not in EXPORT_FORMATS:
        raise UserInputError(f"--export {str(out)!r}: give a file ending in "
                             f"{', '.join(EXPORT_FORMATS)} (GLB for Foxglove, Blender and "
                             "Gazebo).")
    return check_output_file(out, "--export")


def export_scene_mesh(xml: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Writes a scene's walls and floor as a mesh file (GLB, OBJ, STL or PLY), atomically.

    Coordinates are metres in the ``map`` frame; GLB and OBJ are y-up, (x, y, z) ->
    (x, z, -y); STL and PLY z-up (see the module docstring).

    Raises:
        UserInputError: unsupported suffix, or the MJCF is not a scene.
    """
    out = check_export_path(out)
    suffix = out.suffix.lower()
    meshes = scene_meshes(xml)
    colours = {"walls": [158, 163, 179, 255], "floor": [209, 209, 204, 255]}
    to_file = Y_UP_TO_Z_UP.T if MESH_FORMATS[suffix] == "y" else np.eye(3)
    scene = trimesh.Scene()
    for name, mesh in meshes.items():
        mesh = trimesh.Trimesh(mesh.vertices @ to_file.T, mesh.faces, process=False,
                               face_colors=np.tile(colours[name], (len(mesh.faces), 1)))
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    if suffix == ".glb":
        data = scene.export(file_type="glb")
    else:
        data = scene.to_mesh().export(file_type=suffix[1:])
    write_bytes_atomic(out, data if isinstance(data, bytes) else data.encode())
    return out


__all__ = [
    "MESH_FORMATS",
    "MESH_UNITS",
    "MeshImportConfig",
    "check_export_path",
    "check_scale",
    "cluster_simplify",
    "export_scene_mesh",
    "floor_level",
    "lidar_height",
    "load_mesh",
    "rasterise_segments",
    "rasterise_triangles",
    "scene_from_mesh",
    "scene_meshes",
    "units_scale",
    "visual_mesh",
    "wall_cells",
    "wall_segments",
]
