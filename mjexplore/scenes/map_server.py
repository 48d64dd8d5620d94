"""Reading and writing ROS ``map_server`` maps (a YAML file and an image).

Format (ROS wiki ``map_server``, as ROS 1's ``image_loader`` reads it): the YAML holds
``image`` (path relative to the YAML), ``resolution`` (metres per pixel), ``origin``
([x, y, yaw] of the lower-left pixel), ``negate``, ``occupied_thresh``, ``free_thresh`` and
``mode``. A pixel's value ``v`` is the mean of its channels (as a real number; in
``trinary`` mode an alpha channel is averaged in, in the others it is left out), ``255 - v``
when ``negate``. Its occupancy is ``p = (255 - v) / 255``:

* ``trinary`` (default): ``p > occupied_thresh`` occupied (100), ``p < free_thresh`` free
  (0), anything else unknown (-1);
* ``scale``: the same, except that values in between are ``int(99 (p - free_thresh) /
  (occupied_thresh - free_thresh))`` unless the pixel is fully transparent (unknown);
* ``raw``: ``int(v)`` is the cell value itself (0-100, 255 for unknown).

Image rows run top (highest y) to bottom. Written maps use ``map_saver``'s values: 254
free, 0 occupied, 205 unknown.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import yaml

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic, write_text_atomic
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap

PGM_FREE = 254
PGM_OCCUPIED = 0
PGM_UNKNOWN = 205
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


MODES = ("trinary", "scale", "raw")


def _read_image(path: Path) -> np.ndarray:
    """An 8-bit image as OpenCV decodes it: (rows, cols) or (rows, cols, channels)."""
    if not path.is_file():
        raise UserInputError(f"map image {str(path)!r} does not exist: check the path (a map "
                             "YAML's 'image' is relative to the YAML file's folder).")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise UserInputError(f"map image {str(path)!r} could not be decoded: give a PGM or PNG "
                             "image (8 bits per channel); re-save it if it is truncated.")
    if img.dtype != np.uint8:
        raise UserInputError(f"map image {str(path)!r} has {img.dtype} pixels: convert it to "
                             "8 bits per channel.")
    return img


def read_image_gray(path: str | os.PathLike) -> np.ndarray:
    """Reads an 8-bit image as greyscale: the integer mean of its colour channels, alpha
    ignored (plain images; map_server maps go through :func:`read_map`).

    Raises:
        UserInputError: the file is missing or is not an 8-bit image OpenCV can decode.
    """
    img = _read_image(Path(path))
    if img.ndim == 3:
        channels = img[..., :3] if img.shape[2] >= 3 else img[..., :1]
        img = (channels.astype(np.uint16).sum(axis=2) // channels.shape[2]).astype(np.uint8)
    return img


def _pixel_values(img: np.ndarray, mode: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(mean channel value as float, alpha or None) per pixel, as map_server averages."""
    if img.ndim == 2:
        return img.astype(np.float64), None
    has_alpha = img.shape[2] in (2, 4)
    alpha = img[..., -1] if has_alpha else None
    averaged = img if mode == "trinary" or not has_alpha else img[..., :-1]
    return averaged.astype(np.float64).mean(axis=2), alpha


def _require(meta: dict, key: str, path: Path):
    if key not in meta:
        raise UserInputError(f"map YAML {str(path)!r} has no {key!r} entry: a map_server YAML "
                             "needs image, resolution and origin.")
    return meta[key]


# What each numeric entry is, for messages.
_NUMBERS = {"resolution": "metres per pixel, e.g. 0.05",
            "negate": "0 or 1; drop the line for 0",
            "occupied_thresh": f"a number in [0, 1]; drop the line for map_saver's "
                               f"{OCCUPIED_THRESH}",
            "free_thresh": f"a number in [0, 1]; drop the line for map_saver's {FREE_THRESH}"}


def _is_number(value) -> bool:
    """A YAML number a float holds (not a bool, not a whole number beyond float's range)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        float(value)
    except OverflowError:
        return False
    return True


def _number(meta: dict, key: str, path: Path, default: float | None = None) -> float:
    """The number ``meta[key]`` (``default`` when the key is absent; required without one)."""
    value = _require(meta, key, path) if default is None else meta.get(key, default)
    if key == "negate" and isinstance(value, bool):
        return float(value)  # YAML's true and false.
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if not _is_number(value):
        what = "is empty" if value is None else f"is {value!r}, not a number"
        raise UserInputError(f"map YAML {str(path)!r}: {key} {what}: give {_NUMBERS[key]}.")
    return float(value)


def read_map(yaml_path: str | os.PathLike) -> GridMap:
    """Reads a map_server map into a :class:`GridMap` (trinary interpretation).

    Raises:
        UserInputError: a missing or malformed YAML or image, with what to fix.
    """
    yaml_path = Path(yaml_path)
    if not yaml_path.is_file():
        raise UserInputError(f"map YAML {str(yaml_path)!r} does not exist: check the path.")
    try:
        meta = yaml.safe_load(yaml_path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise UserInputError(f"map YAML {str(yaml_path)!r} is not valid YAML ({exc}): fix "
                             "the file or re-save the map with map_saver.") from None
    if not isinstance(meta, dict):
        raise UserInputError(f"map YAML {str(yaml_path)!r} is not a mapping of keys: it must "
                             "hold image, resolution, origin, ...")
    image = _require(meta, "image", yaml_path)
    resolution = _number(meta, "resolution", yaml_path)
    origin = _require(meta, "origin", yaml_path)
    if not isinstance(origin, list) or not all(_is_number(v) for v in origin):
        raise UserInputError(f"map YAML {str(yaml_path)!r}: origin {origin!r} is not [x, y, yaw]: "
                             "give three numbers in metres and radians, e.g. [0.0, 0.0, 0.0].")
    origin = [float(v) for v in origin]
    negate = _number(meta, "negate", yaml_path, 0)
    mode = str(meta.get("mode", "trinary"))
    occ_th = _number(meta, "occupied_thresh", yaml_path, OCCUPIED_THRESH)
    free_th = _number(meta, "free_thresh", yaml_path, FREE_THRESH)
    if not resolution > 0 or len(origin) != 3:
        raise UserInputError(f"map YAML {str(yaml_path)!r}: resolution must be > 0 and origin "
                             "must be [x, y, yaw].")
    if origin[2] != 0.0:
        raise UserInputError(f"map YAML {str(yaml_path)!r}: origin yaw {origin[2]} is not "
                             "supported; rotate the image instead so that yaw is 0.")
    if not 0.0 <= free_th < occ_th <= 1.0:
        raise UserInputError(f"map YAML {str(yaml_path)!r}: need 0 <= free_thresh < "
                             "occupied_thresh <= 1.")
    if mode not in MODES:
        raise UserInputError(f"map YAML {str(yaml_path)!r}: mode {mode!r} is not one of "
                             f"{', '.join(MODES)}.")
    value, alpha = _pixel_values(_read_image(yaml_path.parent / str(image)), mode)
    if negate:
        value = 255.0 - value
    if mode == "raw":
        raw = value.astype(np.int64)  # map_server truncates to an unsigned char.
        if not ((raw <= OCCUPIED) | (raw == 255)).all():
            raise UserInputError(f"map YAML {str(yaml_path)!r} is in raw mode but its image "
                                 "has values other than 0-100 and 255 (unknown): use mode "
                                 "trinary or scale for a greyscale picture.")
        data = np.where(raw == 255, UNKNOWN, raw).astype(np.int8)
    else:
        occupancy = (255.0 - value) / 255.0
        data = np.full(value.shape, UNKNOWN, dtype=np.int8)
        if mode == "scale":
            between = (occupancy >= free_th) & (occupancy <= occ_th)
            if alpha is not None:
                between &= alpha > 0
            data[between] = (99.0 * (occupancy[between] - free_th)
                             / (occ_th - free_th)).astype(np.int8)
        data[occupancy > occ_th] = OCCUPIED
        data[occupancy < free_th] = FREE
    return GridMap(np.ascontiguousarray(data[::-1]), resolution, (origin[0], origin[1], 0.0))


def encode_pgm(grid: GridMap, comment: str = "mjexplore") -> bytes:
    """Encodes a grid as a binary PGM with map_saver's values (254 free, 0 occ, 205 unknown)."""
    pixels = np.full(grid.shape, PGM_UNKNOWN, dtype=np.uint8)
    pixels[grid.free] = PGM_FREE
    pixels[grid.occupied] = PGM_OCCUPIED
    rows, cols = grid.shape
    header = f"P5\n# CREATOR: {comment} {grid.resolution:.3f} m/pix\n{cols} {rows}\n255\n"
    return header.encode("ascii") + np.ascontiguousarray(pixels[::-1]).tobytes()


def map_yaml_text(image_name: str, grid: GridMap) -> str:
    x, y, yaw = grid.origin
    return (
        f"image: {image_name}\n"
        f"mode: trinary\n"
        f"resolution: {grid.resolution:.6f}\n"
        f"origin: [{x:.6f}, {y:.6f}, {yaw:.6f}]\n"
        f"negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
    )


def write_map(yaml_path: str | os.PathLike, grid: GridMap) -> None:
    """Writes ``grid`` as a map_server pair: ``NAME.yaml`` and ``NAME.pgm`` beside it.

    The trinary view of the grid (free, occupied, unknown) is what is stored.
    """
    yaml_path = Path(yaml_path)
    pgm_path = yaml_path.with_suffix(".pgm")
    write_bytes_atomic(pgm_path, encode_pgm(grid))
    write_text_atomic(yaml_path, map_yaml_text(pgm_path.name, grid))
