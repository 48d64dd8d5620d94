"""The canonical scenes committed under ``scenes_xml/`` and name-or-path resolution.

``tools/regenerate_scenes.py`` rebuilds them from this table bit for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shlex
import tempfile
from pathlib import Path

import yaml

from mjexplore.errors import UserInputError
from mjexplore.robot import ROBOT_XML, turtlebot3
from mjexplore.scenes.scene import SCENE_FORMS, SceneFiles, load_scene_files

SCENES_DIR = Path(os.environ.get("MJEXPLORE_SCENES",
                                 Path(__file__).resolve().parents[2] / "scenes_xml"))


@dataclasses.dataclass(frozen=True)
class CanonicalScene:
    """How a canonical scene is generated.

    Attributes:
        family: Generator family (or '+'-joined families).
        size: (width, height) in metres.
        seed: Generator seed.
        role: 'eval', 'train', 'real' (the real-robot lobby) or 'extra' (an example of a
            family beyond the paper's set).
        note: What the scene stands for.
    """

    family: str
    size: tuple[float, float]
    seed: int
    role: str
    note: str


CANONICAL_SCENES: dict[str, CanonicalScene] = {
    # The paper's three evaluation scenes (Fig. 6).
    "loop_with_corridor": CanonicalScene("loop", (24, 24), 3, "eval",
                                         "Scene 1: loop with corridor, 24 x 24 m"),
    "maze": CanonicalScene("maze", (20, 20), 0, "eval", "Scene 2: maze, 20 x 20 m"),
    "office": CanonicalScene("office", (40, 25), 0, "eval", "Scene 3: office, 40 x 25 m"),
    # Nine training scenes (Fig. 4): basic layouts, combinations and large ones.
    "train_loop": CanonicalScene("loop", (16, 16), 1, "train", "loop"),
    "train_narrow_corridor": CanonicalScene("corridor", (20, 12), 2, "train", "narrow corridor"),
    "train_rooms": CanonicalScene("rooms", (18, 14), 3, "train", "multiple rooms"),
    "train_office_small": CanonicalScene("office", (24, 16), 4, "train", "small office"),
    "train_loop_rooms": CanonicalScene("loop+rooms", (30, 18), 5, "train", "loop and rooms"),
    "train_corridor_rooms": CanonicalScene("corridor+rooms", (28, 16), 6, "train",
                                           "corridor and rooms"),
    "train_maze_loop": CanonicalScene("maze+loop", (30, 16), 7, "train", "maze and loop"),
    "train_large_office": CanonicalScene("office", (50, 30), 8, "train", "large office"),
    "train_large_combo": CanonicalScene("rooms+loop+corridor", (48, 30), 9, "train",
                                        "large combination"),
    # The paper's real-robot setting: a 17.5 x 4 m lobby.
    "lobby": CanonicalScene("hall", (17.5, 4), 0, "real", "real-robot lobby, 17.5 x 4 m"),
    # Beyond the paper: DeepMind Lab's maze distribution (labmaze, as dm_control uses it).
    "labmaze": CanonicalScene("labmaze", (20, 20), 0, "extra",
                              "DeepMind Lab random maze (labmaze), 20 x 20 m"),
}


# Explore-Bench's single-robot start poses (x, y, yaw) in map coordinates (its README).
EXPLORE_BENCH_STARTS = {"corner": (6.0, 6.0, 1.57)}
EXPLORE_BENCH_DEFAULT_START = (8.0, 8.0, 1.57)
EXPLORE_BENCH_MAPS = ("corner", "corridor", "loop", "loop_with_corridor", "room",
                      "room_with_corner")


def canonical_names(role: str | None = None) -> list[str]:
    return [n for n, c in CANONICAL_SCENES.items() if role is None or c.role == role]


# The files that decide what an import builds (its code and the robot model it places): a
# change to any of them makes earlier imports stale.
IMPORT_CODE = tuple(Path(__file__).with_name(name) for name in (
    "canonical.py", "importer.py", "map_server.py", "scene.py", "mesh.py",
    "rectangles.py")) + (Path(turtlebot3.__file__), ROBOT_XML)
# Files that hold a picture of a map, not a scene (``--scene`` refuses them with how to
# import one).
IMAGE_SUFFIXES = (".pgm", ".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pbm", ".tif", ".tiff",
                  ".gif", ".webp")


def _import_digest(path: Path, start) -> str:
    """Cache key of an imported map: its YAML, its image, the start pose rule and the code
    that imports it (``IMPORT_CODE``)."""
    digest = hashlib.sha256(path.read_bytes())
    for module in IMPORT_CODE:
        digest.update(module.read_bytes())
    try:
        image = yaml.safe_load(path.read_text()).get("image")
        digest.update((path.parent / image).read_bytes())
    except (OSError, ValueError, AttributeError, TypeError, yaml.YAMLError):
        pass  # The import itself says what is wrong with the map.
    digest.update(repr(start).encode())
    return digest.hexdigest()[:16]


def explore_bench_map(yaml_path: str | os.PathLike) -> str | None:
    """The name of the Explore-Bench map a map_server YAML is (a YAML named like one of
    :data:`EXPLORE_BENCH_MAPS` in a folder named ``explore_bench``), or None."""
    path = Path(yaml_path)
    if path.resolve().parent.name == "explore_bench" and path.stem in EXPLORE_BENCH_MAPS:
        return path.stem
    return None


def _not_a_scene(path: Path) -> None:
    """Refuses an image or a 3D model given where a scene is expected, with how to import
    it (they are not MJCF, and MuJoCo's parser would only say it cannot decode them)."""
    suffix = path.suffix.lower()
    what = f"a scene is {SCENE_FORMS}"
    if suffix in IMAGE_SUFFIXES:
        beside = [p for p in (path.with_suffix(".yaml"), path.with_suffix(".yml"))
                  if p.is_file()]
        use = (f"give its map_server YAML ({str(beside[0])!r}), or import the image"
               if beside else "import it")
        raise UserInputError(
            f"{str(path)!r} is an image, not a scene: {what}; {use} with 'mjexplore scene-gen "
            f"--from-map {shlex.quote(str(path))} --resolution METRES_PER_PIXEL --out DIR' "
            "(bright pixels free) and give --scene DIR.")
    from mjexplore.scenes.mesh import MESH_FORMATS

    if suffix in MESH_FORMATS:
        raise UserInputError(
            f"{str(path)!r} is a 3D model, not a scene: {what}; import it with 'mjexplore "
            f"scene-gen --from-mesh {shlex.quote(str(path))} --out DIR' and give --scene DIR.")


def resolve_scene(scene: str | os.PathLike) -> SceneFiles:
    """Finds a scene by canonical name, scene folder, MJCF path or map_server YAML path.

    A map_server YAML is imported into a scene folder under the system's temporary
    directory (keyed by the map's content, so it is built once). Explore-Bench's maps (a
    YAML named like one of them in a folder named ``explore_bench``) start at the
    benchmark's standard pose, and their metadata names the map (``explore_bench``: its
    two-robot placements apply to them only); other maps start at a seeded free pose.

    Raises:
        UserInputError: no such scene, or an image or a 3D model (says how to import it).
    """
    text = str(scene)
    if text in CANONICAL_SCENES:
        folder = SCENES_DIR / text
        if not (folder / "scene.xml").is_file():
            raise UserInputError(f"canonical scene {text!r} is missing from {SCENES_DIR}: run "
                                 "'python tools/regenerate_scenes.py' to rebuild it.")
        return load_scene_files(folder)
    path = Path(text)
    if path.suffix.lower() in (".yaml", ".yml") and path.is_file():
        from mjexplore.scenes.importer import scene_from_map_yaml
        from mjexplore.scenes.scene import write_scene

        start, bench_map = None, explore_bench_map(path)
        if bench_map is not None:
            start = EXPLORE_BENCH_STARTS.get(bench_map, EXPLORE_BENCH_DEFAULT_START)
        digest = _import_digest(path, start)
        folder = Path(tempfile.gettempdir()) / "mjexplore-scenes" / f"{path.stem}-{digest}"
        if not (folder / "scene.xml").is_file():
            imported = scene_from_map_yaml(path, start=start)
            if bench_map is not None:  # Its team placements apply (scenes/team.py).
                imported = dataclasses.replace(
                    imported, metadata={**imported.metadata, "explore_bench": bench_map})
            write_scene(imported, folder)
        return load_scene_files(folder)
    if path.is_file():
        _not_a_scene(path)
    if not path.exists():
        raise UserInputError(f"unknown scene {text!r}: give one of "
                             f"{', '.join(CANONICAL_SCENES)}, a scene folder, an MJCF file or a "
                             "map_server YAML.")
    return load_scene_files(path)
