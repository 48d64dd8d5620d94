"""Scenes with a team of robots: start poses, and one MJCF with N Turtlebots.

A team's model is the scene's own MJCF with its robot replaced by N copies of it, each
under the name prefix ``robot_{i}/`` (``robot_0/base_link``, ``robot_1/wheel_left``, ...),
so that every robot has its own joints, motors, IMU and lidar frame. Each copy also carries
a *silhouette*: a box over the body's footprint from the base plate to the top of the
lidar, which is what a teammate's horizontal scan plane meets (geom group
:data:`SILHOUETTE_GROUP`, which renderers hide by default; no contacts, no mass; not fully
transparent, since MuJoCo's rays skip geoms of alpha 0); the lidar casts against the walls
and these (:class:`mjexplore.sim.simulator.Simulator` with ``starts``). The robots'
collision geoms collide with each other as with the walls.

Start poses come from the command line (:func:`parse_starts`), from Explore-Bench's
two-robot launch files (:data:`EXPLORE_BENCH_TEAM_STARTS`: "close" and "far" placements of
its six maps), or are drawn from a seed around the first robot (:func:`draw_starts`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import mujoco
import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.scene import check_start, clearance, reachable_region

Pose = tuple[float, float, float]

ROBOT_BASE = "base_link"
SILHOUETTE_GROUP = 5
SILHOUETTE = "silhouette"
# The silhouette box about base_link, metres: the base plate's footprint (0.281 x 0.266 m,
# centred 0.064 m behind the axle), from the plate's underside to the top of the LDS.
SILHOUETTE_POS = (-0.064, 0.0, 0.077)
SILHOUETTE_HALF = (0.1405, 0.133, 0.0645)

# Explore-Bench's two-robot start poses (x, y, yaw) in map coordinates, from its Gazebo
# launch files (sim_env/launch/simulation_environment/*_{close,far}*_two_robots.launch,
# efc-robot/Explore-Bench at e8b0438): "close" starts 2-3 m apart, "far" at opposite
# corners of the building. One exception: corner's far poses, (8, 8) and (-8, -8), lie in
# its walls on the blueprint (the benchmark's own single-robot start moves to (6, 6) there
# for that reason), so here robot 0 starts at (6, 6) and robot 1 at (-7, -7), the point
# nearest the mirror image with room for the robot.
EXPLORE_BENCH_TEAM_STARTS: dict[str, dict[str, tuple[Pose, Pose]]] = {
    "corner": {"close": ((5.0, 7.0, 1.57), (7.0, 5.0, 1.57)),
               "far": ((6.0, 6.0, 1.57), (-7.0, -7.0, 1.57))},
    "corridor": {"close": ((8.0, 7.0, 1.57), (8.0, 9.0, 1.57)),
                 "far": ((8.0, 8.0, 1.57), (-8.0, -8.0, 1.57))},
    "loop": {"close": ((9.0, 7.0, 1.57), (7.0, 9.0, 1.57)),
             "far": ((8.0, 8.0, 1.57), (-8.0, -8.0, 1.57))},
    "loop_with_corridor": {"close": ((9.0, 7.0, 1.57), (7.0, 9.0, 1.57)),
                           "far": ((8.0, 8.0, 1.57), (-8.0, -8.0, 1.57))},
    "room": {"close": ((1.0, 1.0, 1.57), (-1.0, -1.0, 1.57)),
             "far": ((8.0, 7.5, 1.57), (-7.5, -8.0, 1.57))},
    "room_with_corner": {"close": ((9.0, 7.0, 1.57), (7.0, 9.0, 1.57)),
                         "far": ((8.0, 8.0, 1.57), (-8.0, -8.0, 1.57))},
}
PLACEMENTS = ("close", "far")
# Robots closer than this (base_link to base_link, metres) would overlap or nearly touch.
MIN_SEPARATION = 0.8


def robot_prefix(i: int) -> str:
    """The MJCF name prefix of robot ``i`` in a team's model."""
    return f"robot_{i}/"


def parse_starts(text: str) -> list[Pose]:
    """Start poses from ``"X,Y,YAW;X,Y,YAW;..."`` (metres, radians; YAW may be left out).

    Raises:
        UserInputError: a pose that is not two or three numbers.
    """
    poses = []
    for part in text.split(";"):
        try:
            values = [float(v) for v in part.split(",")]
        except ValueError:
            values = []
        if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
            raise UserInputError(f"start pose {part.strip()!r} in --starts {text!r} is not "
                                 "X,Y[,YAW] in metres and radians; separate robots with ';', "
                                 "e.g. --starts '1,2,0;3,2,1.57'.")
        poses.append((values[0], values[1], values[2] if len(values) == 3 else 0.0))
    return poses


def explore_bench_starts(map_name: str, placement: str) -> list[Pose]:
    """Explore-Bench's two-robot start poses on one of its maps.

    Raises:
        UserInputError: not one of its maps, or an unknown placement.
    """
    if placement not in PLACEMENTS:
        raise UserInputError(f"placement {placement!r} is unknown: use one of "
                             f"{', '.join(PLACEMENTS)}.")
    if map_name not in EXPLORE_BENCH_TEAM_STARTS:
        raise UserInputError(f"'{placement}' starts are Explore-Bench's placements and "
                             f"{map_name!r} is not one of its maps "
                             f"({', '.join(EXPLORE_BENCH_TEAM_STARTS)}): give the poses "
                             "(--starts 'X,Y,YAW;X,Y,YAW') or leave --starts out to draw them.")
    return list(EXPLORE_BENCH_TEAM_STARTS[map_name][placement])


def check_starts(grid: GridMap, starts: list[Pose],
                 min_separation: float = MIN_SEPARATION) -> None:
    """Raises UserInputError unless every start is in free space (:func:`check_start`) and
    the robots stand at least ``min_separation`` metres apart."""
    for pose in starts:
        check_start(grid, pose)
    xy = np.array([p[:2] for p in starts], float).reshape(-1, 2)
    for i in range(len(xy)):
        for j in range(i):
            d = float(np.hypot(*(xy[i] - xy[j])))
            if d < min_separation:
                raise UserInputError(
                    f"robots {j} and {i} start {d:.2f} m apart; they need "
                    f"{min_separation:.2f} m: move one of them.")


def _pack(xy: np.ndarray, d_first: np.ndarray, first: Pose,
          min_separation: float) -> np.ndarray:
    """A dense packing of the places ``xy`` (at distances ``d_first`` from ``first``):
    taken innermost first, each at least ``min_separation`` from ``first`` and from those
    taken before it. Deterministic; its size is the most robots :func:`draw_starts`
    places besides ``first``."""
    taken = [np.asarray(first[:2], float)]
    for k in np.argsort(d_first, kind="stable"):
        if (np.hypot(*(np.asarray(taken) - xy[k]).T) >= min_separation).all():
            taken.append(xy[k])
    return np.asarray(taken[1:], float).reshape(-1, 2)


def draw_starts(grid: GridMap, first: Pose, n: int, rng: np.random.Generator,
                ring: tuple[float, float] = (1.0, 3.0),
                min_clearance: float = 0.5,
                min_separation: float = 1.0) -> list[Pose]:
    """``first`` and ``n - 1`` more start poses drawn around it: a team set down together.

    Each further robot stands ``ring`` (inner, outer radius, metres) from ``first`` in
    straight line, where the robot fits with ``min_clearance`` metres to the walls, in the
    region the first robot can drive to, at least ``min_separation`` from the others; its
    yaw is uniform. Each is drawn uniformly from the places left; when the draw leaves no
    place for the next robot, the team stands at a random choice of the places of a dense
    packing of the ring (:func:`_pack`) instead, and when even that holds too few, the team
    is refused with the most robots that fit.

    Raises:
        UserInputError: the ring has no room for ``n`` robots (says how many fit).
    """
    starts: list[Pose] = [(float(first[0]), float(first[1]), float(first[2]))]
    if n <= 1:
        return starts[:n]
    res = grid.resolution
    seed = grid.world_to_cell(np.array(first[:2]))
    cspace, _ = reachable_region(grid.free, res, (int(seed[0]), int(seed[1])))
    room = cspace & (clearance(grid.free, res) >= max(min_clearance,
                                                      TURTLEBOT3_WAFFLE.footprint_radius))
    rows, cols = np.nonzero(room)
    xy = grid.cell_to_world(np.column_stack([rows, cols])).reshape(-1, 2)
    d_first = np.hypot(*(xy - np.asarray(first[:2])).T)
    inner, outer = ring
    in_ring = (d_first >= inner) & (d_first <= outer)
    xy, d_first = xy[in_ring], d_first[in_ring]
    while len(starts) < n:
        placed = np.array([p[:2] for p in starts])
        apart = (np.hypot(xy[:, None, 0] - placed[None, :, 0],
                          xy[:, None, 1] - placed[None, :, 1]) >= min_separation).all(axis=1)
        ok = np.flatnonzero(apart)
        if len(ok) == 0:
            break
        k = int(ok[rng.integers(len(ok))])
        yaw = float(rng.uniform(-math.pi, math.pi))
        starts.append((round(float(xy[k, 0]), 4), round(float(xy[k, 1]), 4), round(yaw, 4)))
    if len(starts) == n:
        return starts
    packed = _pack(xy, d_first, first, min_separation)
    fit = 1 + len(packed)
    if fit < n:
        raise UserInputError(
            f"{n} robots do not fit around the start ({first[0]:.2f}, {first[1]:.2f}): the "
            f"others are drawn {inner:g}-{outer:g} m from robot 0, {min_separation:g} m "
            f"apart and {min_clearance:g} m from walls, where this map has room for "
            f"{fit - 1} more (at most {fit} robots): use --robots {fit} or fewer.")
    chosen = np.sort(rng.choice(len(packed), n - 1, replace=False))
    yaws = rng.uniform(-math.pi, math.pi, size=n - 1)
    return starts[:1] + [(round(float(packed[k, 0]), 4), round(float(packed[k, 1]), 4),
                          round(float(yaw), 4)) for k, yaw in zip(chosen, yaws)]


def _yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def team_spec(xml: str | os.PathLike, starts: list[Pose]) -> mujoco.MjSpec:
    """The scene's MJCF with its robot replaced by ``len(starts)`` copies of it.

    Robot ``i`` stands at ``starts[i]`` (its ``qpos0``); its names carry the prefix
    :func:`robot_prefix`; its base carries a silhouette geom (module docstring).

    Raises:
        UserInputError: the MJCF does not hold the robot, or no start is given.
    """
    if not starts:
        raise UserInputError("a team needs at least one robot (give --robots 1 or more).")
    xml = Path(xml)
    spec = mujoco.MjSpec.from_file(str(xml))
    try:
        base = spec.body(ROBOT_BASE)
    except Exception:  # noqa: BLE001 - MjSpec raises a bare error type for missing names.
        base = None
    if base is None:
        raise UserInputError(f"MJCF {str(xml)!r} has no body '{ROBOT_BASE}': a team replaces "
                             "the scene's robot, so the scene must contain one.")
    z0 = float(base.pos[2])
    # The scene's actuators and sensors are its robot's (scene MJCFs hold nothing else).
    for element in list(spec.actuators) + list(spec.sensors):
        spec.delete(element)
    spec.delete(base)
    for i, (x, y, yaw) in enumerate(starts):
        source = mujoco.MjSpec.from_file(str(xml))
        frame = spec.worldbody.add_frame()
        body = frame.attach_body(source.body(ROBOT_BASE), robot_prefix(i), "")
        body.pos = [x, y, z0]
        body.quat = _yaw_quat(yaw)
        body.add_geom(name=robot_prefix(i) + SILHOUETTE, type=mujoco.mjtGeom.mjGEOM_BOX,
                      pos=list(SILHOUETTE_POS), size=list(SILHOUETTE_HALF),
                      group=SILHOUETTE_GROUP, contype=0, conaffinity=0, density=0.0,
                      rgba=[0.3, 0.3, 0.3, 0.3])
    return spec


__all__ = [
    "EXPLORE_BENCH_TEAM_STARTS",
    "MIN_SEPARATION",
    "PLACEMENTS",
    "SILHOUETTE",
    "SILHOUETTE_GROUP",
    "check_starts",
    "draw_starts",
    "explore_bench_starts",
    "parse_starts",
    "robot_prefix",
    "team_spec",
]
