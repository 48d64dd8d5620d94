"""Scenes from existing maps: ROS map_server pairs and plain images.

Everything that is not known free in the map becomes wall in the MJCF (occupied cells,
and unknown space too, so the robot cannot leave the mapped area); the ground truth keeps
the map's three classes. Diagonal walls become staircases of boxes at the map's
resolution, so the imported occupancy matches the map cell for cell.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.scenes.map_server import read_image_gray, read_map
from mjexplore.scenes.scene import Scene, check_start, pick_start, reachable_region

# ARiADNE's test maps mark the start with a block of this colour (RGB).
START_MARKER_RGB = (255, 216, 0)
IMAGE_FREE_THRESHOLD = 150
# A map that reaches farther than this from its frame's origin (metres) has a wrong
# resolution or origin (a building is a few hundred metres across at most).
MAX_REACH_M = 1e5


def scene_from_grid(grid: GridMap, name: str, source: dict,
                    start: tuple[float, float, float] | None = None, seed: int = 0) -> Scene:
    """Builds a scene from a ground-truth grid.

    Args:
        grid: The map; free cells stay free, everything else becomes wall.
        name: Scene name.
        source: Provenance stored in ``scene.json``.
        start: Start pose (x, y, yaw) in the map frame; None picks one with ``seed``.
        seed: Seed for picking the start pose.

    Raises:
        UserInputError: the map reaches farther than :data:`MAX_REACH_M` (a wrong
            resolution or origin), has no free space, or the start is not in free space.
    """
    ox, oy, _ = grid.origin
    reach = max(abs(ox), abs(oy)) + max(grid.size_m)
    if not reach <= MAX_REACH_M:  # Also NaN and infinity.
        raise UserInputError(
            f"map {name!r} reaches {reach:.3g} m from its frame's origin (resolution "
            f"{grid.resolution:g} m per pixel, origin ({ox:g}, {oy:g}) m), more than "
            f"{MAX_REACH_M:g} m: check its resolution (metres per pixel, e.g. 0.05) and "
            "origin (metres).")
    free = grid.free
    if not free.any():
        raise UserInputError(f"map {name!r} has no free cells: check its thresholds "
                             "(occupied_thresh, free_thresh, negate) or the image's colours.")
    if start is None:
        sx, sy, yaw = pick_start(free, grid.resolution, np.random.default_rng(seed))
        start = (round(ox + sx, 4), round(oy + sy, 4), yaw)
    check_start(grid, start)
    seed_cell = tuple(grid.world_to_cell(np.array(start[:2])))
    _, reachable = reachable_region(free, grid.resolution, seed_cell)
    metadata = dict(source)
    metadata["reachable_free_fraction"] = round(float(reachable.sum() / free.sum()), 4)
    return Scene(name=name, ground_truth=grid, solid=~free, start=(start[0], start[1], start[2]),
                 metadata=metadata)


def scene_from_map_yaml(yaml_path: str | os.PathLike,
                        start: tuple[float, float, float] | None = None,
                        seed: int = 0) -> Scene:
    """Imports a map_server map (YAML + image) as a scene."""
    yaml_path = Path(yaml_path)
    grid = read_map(yaml_path)
    return scene_from_grid(grid, yaml_path.stem, {"source": "map_server",
                                                  "map": yaml_path.name}, start, seed)


def scene_from_image(image_path: str | os.PathLike, resolution: float,
                     start: tuple[float, float, float] | None = None, seed: int = 0,
                     free_threshold: int = IMAGE_FREE_THRESHOLD) -> Scene:
    """Imports a plain image (bright pixels free, the rest wall) as a scene.

    The origin is the image's lower-left corner. If the image holds a block of the start
    marker colour (255, 216, 0), as ARiADNE's maps do, its centre is the start position.

    Args:
        image_path: PNG (or any 8-bit image OpenCV reads).
        resolution: Metres per pixel.
        start: Start pose; overrides the marker.
        seed: Seed for the yaw (and the position when there is no marker).
        free_threshold: Grey level above which a pixel is free.
    """
    import cv2

    image_path = Path(image_path)
    if not resolution > 0:
        raise UserInputError(f"resolution {resolution} must be > 0 metres per pixel.")
    gray = read_image_gray(image_path)
    data = np.where(gray > free_threshold, FREE, OCCUPIED).astype(np.int8)[::-1]
    grid = GridMap(np.ascontiguousarray(data), float(resolution), (0.0, 0.0, 0.0))
    if start is None:
        color = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
        assert color is not None  # read_image_gray has read it.
        marker = np.all(color[::-1] == START_MARKER_RGB[::-1], axis=2)
        if marker.any():
            rows, cols = np.nonzero(marker)
            rng = np.random.default_rng(seed)
            start = ((cols.mean() + 0.5) * resolution, (rows.mean() + 0.5) * resolution,
                     round(float(rng.uniform(-math.pi, math.pi)), 4))
    return scene_from_grid(grid, image_path.stem, {"source": "image", "image": image_path.name,
                                                   "free_threshold": free_threshold},
                           start, seed)


__all__ = ["scene_from_grid", "scene_from_image", "scene_from_map_yaml"]
