"""Seeded floor-plan generators: office, maze, loop, corridor, rooms, hall, labmaze, dungeon,
and combinations.

Every generator carves free space out of a solid grid (``True`` = wall). A generator owns a
region (an axis-aligned rectangle in metres) and keeps a solid margin of half the wall
thickness along its border, so that two neighbouring regions leave a wall of the full
thickness between them and the outer wall of the scene is also one thickness thick.

Families:
    office: a main corridor with cross corridors; the blocks beside them split into rooms
        with doors to the corridors (or to a neighbouring room).
    rooms: a binary-space partition into rooms joined by doors (a spanning tree plus a few
        extra doors, so there are loops).
    maze: a perfect maze on a square cell lattice, with a few walls removed (braided).
    loop: a ring corridor round a solid core, optionally crossed by a corridor, with
        dead-end corridors (some ending in a small room): the paper's "loop with corridor".
    corridor: narrow corridors (0.9-1.2 m) along a random tree on a lattice.
    hall: one open room with pillars and furniture-sized blocks (the real-robot lobby).
    labmaze: DeepMind Lab's random mazes (the ``labmaze`` package: rooms joined by
        corridors), see :mod:`mjexplore.scenes.labmaze_family`.
    dungeon: a roguelike dungeon: rectangular rooms of 3-10 m a side scattered without
        overlap, joined by straight or L-shaped corridors along a spanning tree of the rooms
        plus a few extra ones (loops). Written from the public description of the
        generator behind ARiADNE's (Cao et al., ICRA 2023) training and test maps.
    Combinations, e.g. ``loop+rooms``: the area is split along its long side into one part
    per family, and neighbouring parts are joined by passages.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.labmaze_family import (
    SEED_BOUND,
    WALL,
    LabmazeConfig,
    entity_layer,
    text_edges,
)
from mjexplore.scenes.scene import MAX_UNREACHABLE_SHARE, clearance, unreachable_share


@dataclasses.dataclass(frozen=True, kw_only=True)
class GeneratorConfig:
    """Dimensions used by the generators, in metres.

    Attributes:
        wall_thickness: Thickness of interior and outer walls.
        door_width: (min, max) width of doors between rooms.
        room_size: (min, max) side length of rooms in ``office`` and ``rooms``; the min is
            also the smallest ``dungeon`` room side.
        office_corridor_width: (min, max) width of office corridors.
        loop_corridor_width: (min, max) width of the ``loop`` ring and its corridors, and of
            ``dungeon`` corridors.
        narrow_corridor_width: (min, max) width of ``corridor`` passages.
        maze_cell: Side of a maze cell (passage width plus one wall).
        extra_door_probability: Chance that a pair of neighbouring rooms gets a second door
            (``dungeon``: a corridor of its own besides the spanning tree's).
        labmaze: The ``labmaze`` family's knobs (cell pitch, rooms, extra connections).
    """

    wall_thickness: float = 0.15
    door_width: tuple[float, float] = (0.9, 1.2)
    room_size: tuple[float, float] = (3.0, 7.0)
    office_corridor_width: tuple[float, float] = (1.6, 2.4)
    loop_corridor_width: tuple[float, float] = (1.2, 2.0)
    narrow_corridor_width: tuple[float, float] = (0.9, 1.2)
    maze_cell: float = 2.0
    extra_door_probability: float = 0.15
    labmaze: LabmazeConfig = dataclasses.field(default_factory=LabmazeConfig)

    def __post_init__(self) -> None:
        if not 0.05 <= self.wall_thickness <= 1.0:
            raise UserInputError(f"wall thickness {self.wall_thickness} m is out of range: use "
                                 "a value from 0.05 to 1.0 m.")


@dataclasses.dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle [x0, x1] x [y0, y1] in metres."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def w(self) -> float:
        return self.x1 - self.x0

    @property
    def h(self) -> float:
        return self.y1 - self.y0

    def inset(self, d: float) -> Rect:
        return Rect(self.x0 + d, self.y0 + d, self.x1 - d, self.y1 - d)


class Canvas:
    """A solid grid that generators carve free space from.

    Args:
        width: Size along x in metres.
        height: Size along y in metres.
        resolution: Cell side in metres.
    """

    def __init__(self, width: float, height: float, resolution: float) -> None:
        self.resolution = resolution
        self.solid = np.ones((round(height / resolution), round(width / resolution)), bool)

    def _cells(self, r: Rect) -> tuple[slice, slice]:
        res = self.resolution
        rows, cols = self.solid.shape
        c0 = min(max(round(r.x0 / res), 0), cols)
        c1 = min(max(round(r.x1 / res), 0), cols)
        r0 = min(max(round(r.y0 / res), 0), rows)
        r1 = min(max(round(r.y1 / res), 0), rows)
        return slice(r0, r1), slice(c0, c1)

    def carve(self, r: Rect) -> None:
        """Makes the cells of ``r`` free (cell edges snap to the grid)."""
        self.solid[self._cells(r)] = False

    def fill(self, r: Rect) -> None:
        """Makes the cells of ``r`` solid."""
        self.solid[self._cells(r)] = True


# ---------------------------------------------------------------------------- partitions


@dataclasses.dataclass
class _Region:
    rect: Rect
    corridor: bool = False


def _uniform(rng: np.random.Generator, low: float, high: float, size: int | None = None):
    """``rng.uniform(low, high)``, taking a range that round-off left a hair below ``low``
    as empty (``low``); a range shorter than that is a region too small for its layout."""
    if high < low - 1e-6:
        raise UserInputError("the scene is too small for this layout at this seed: make it "
                             "larger, the walls thinner, or try another --seed.")
    return rng.uniform(low, max(low, high), size)


def _bsp(rect: Rect, rng: np.random.Generator, lo: float, hi: float) -> list[Rect]:
    """Splits ``rect`` recursively until every side is at most ``hi`` (and at least ``lo``)."""
    out: list[Rect] = []
    stack = [rect]
    while stack:
        r = stack.pop()
        can_x, can_y = r.w >= 2 * lo, r.h >= 2 * lo
        must = r.w > hi or r.h > hi
        if not (can_x or can_y) or not (must or rng.random() < 0.25 and max(r.w, r.h) > 1.5 * lo):
            out.append(r)
            continue
        split_x = can_x and (not can_y or r.w > r.h or (r.w == r.h and rng.random() < 0.5))
        if split_x:
            x = _uniform(rng, r.x0 + lo, r.x1 - lo)
            stack += [Rect(r.x0, r.y0, x, r.y1), Rect(x, r.y0, r.x1, r.y1)]
        else:
            y = _uniform(rng, r.y0 + lo, r.y1 - lo)
            stack += [Rect(r.x0, r.y0, r.x1, y), Rect(r.x0, y, r.x1, r.y1)]
    return out


def _shared_edge(a: Rect, b: Rect, eps: float = 1e-6) -> tuple[str, float, float, float] | None:
    """The boundary segment two touching rectangles share: (axis, coord, lo, hi) or None.

    ``axis`` is 'x' for a vertical shared line at x = coord spanning y in [lo, hi], 'y' for a
    horizontal one at y = coord spanning x in [lo, hi].
    """
    for axis, (a0, a1, b0, b1, s0, s1, t0, t1) in (
        ("x", (a.x0, a.x1, b.x0, b.x1, a.y0, a.y1, b.y0, b.y1)),
        ("y", (a.y0, a.y1, b.y0, b.y1, a.x0, a.x1, b.x0, b.x1)),
    ):
        for coord in (c for c in (a1, a0) if abs(c - b0) < eps or abs(c - b1) < eps):
            if (abs(coord - a1) < eps and abs(coord - b0) < eps) or (
                abs(coord - a0) < eps and abs(coord - b1) < eps
            ):
                lo, hi = max(s0, t0), min(s1, t1)
                if hi > lo:
                    return axis, coord, lo, hi
    return None


def _opening(axis: str, coord: float, lo: float, hi: float, t: float) -> Rect:
    """The rectangle that removes the wall on a shared line between ``lo`` and ``hi``."""
    if axis == "x":
        return Rect(coord - t, lo, coord + t, hi)
    return Rect(lo, coord - t, hi, coord + t)


def _carve_partition(canvas: Canvas, regions: list[_Region], rng: np.random.Generator,
                     cfg: GeneratorConfig) -> None:
    """Carves rooms and corridors of a partition and joins them by doors.

    Corridors that touch are opened to each other along their whole shared edge. Every
    room gets a door along a random spanning tree grown from the corridors (preferring a
    door to a corridor), and neighbouring rooms get an extra door with
    ``cfg.extra_door_probability``.
    """
    t = cfg.wall_thickness
    half = t / 2
    for reg in regions:
        canvas.carve(reg.rect.inset(half))
    edges: dict[tuple[int, int], tuple[str, float, float, float]] = {}
    for i in range(len(regions)):
        for j in range(i + 1, len(regions)):
            shared = _shared_edge(regions[i].rect, regions[j].rect)
            if shared is not None and shared[3] - shared[2] >= cfg.door_width[0] + t:
                edges[(i, j)] = shared
    for (i, j), (axis, coord, lo, hi) in edges.items():
        if regions[i].corridor and regions[j].corridor:
            canvas.carve(_opening(axis, coord, lo + half, hi - half, t))

    def door(i: int, j: int) -> None:
        axis, coord, lo, hi = edges[(min(i, j), max(i, j))]
        width = min(rng.uniform(*cfg.door_width), hi - lo - t)
        start = rng.uniform(lo + half, max(lo + half, hi - half - width))
        canvas.carve(_opening(axis, coord, start, start + width, t))

    neighbours: dict[int, list[int]] = {i: [] for i in range(len(regions))}
    for i, j in edges:
        neighbours[i].append(j)
        neighbours[j].append(i)
    corridors = [i for i, r in enumerate(regions) if r.corridor]
    connected = set(corridors) if corridors else {int(rng.integers(len(regions)))}
    used: set[tuple[int, int]] = set()
    while len(connected) < len(regions):
        candidates = [(i, j) for i in sorted(connected) for j in neighbours[i]
                      if j not in connected]
        if not candidates:
            break  # Disconnected partition: the validation step fills what is unreachable.
        to_corridor = [c for c in candidates if regions[c[0]].corridor]
        pool = to_corridor or candidates
        i, j = pool[int(rng.integers(len(pool)))]
        door(i, j)
        used.add((min(i, j), max(i, j)))
        connected.add(j)
    for i, j in sorted(edges):
        if (i, j) in used or regions[i].corridor or regions[j].corridor:
            continue
        if rng.random() < cfg.extra_door_probability:
            door(i, j)


def _fitted_width(drawn: float, smallest: float, room: float) -> float | None:
    """A drawn corridor width, narrowed to the room there is; None if even the smallest fails.

    Narrowing (rather than redrawing) keeps every region that fits the draw unchanged, and
    lets a composite scene's narrow parts take the narrow end of the range.

    Args:
        drawn: The width drawn from the configured range, metres.
        smallest: The range's lower end, metres.
        room: The widest corridor the region can take, metres.
    """
    if room < smallest:
        return None
    return min(drawn, room)


def carve_rooms(canvas: Canvas, region: Rect, rng: np.random.Generator,
                cfg: GeneratorConfig) -> None:
    """Rooms from a binary-space partition, joined by doors."""
    lo, hi = cfg.room_size
    rooms = _bsp(region, rng, lo, hi)
    _carve_partition(canvas, [_Region(r) for r in rooms], rng, cfg)


def carve_office(canvas: Canvas, region: Rect, rng: np.random.Generator,
                 cfg: GeneratorConfig) -> None:
    """Rooms off corridors: one main corridor along the long side, cross corridors, rooms."""
    transpose = region.h > region.w
    r = Rect(region.y0, region.x0, region.y1, region.x1) if transpose else region
    lo, hi = cfg.room_size
    cw = _fitted_width(rng.uniform(*cfg.office_corridor_width), cfg.office_corridor_width[0],
                       r.h - 2 * lo)
    if cw is None:
        raise UserInputError(f"office needs at least "
                             f"{2 * lo + cfg.office_corridor_width[0] + cfg.wall_thickness:.1f} m "
                             "on its short side: make the scene larger.")
    yc0 = _uniform(rng, r.y0 + lo, r.y1 - lo - cw)
    yc1 = yc0 + cw
    regions = [_Region(Rect(r.x0, yc0, r.x1, yc1), corridor=True)]
    n_cross = max(0, round(r.w / 16.0))
    xs: np.ndarray | list[float] = (
        np.sort(_uniform(rng, r.x0 + lo, r.x1 - lo - cw, size=n_cross)) if n_cross else [])
    for y0, y1 in ((r.y0, yc0), (yc1, r.y1)):
        cuts = [x for x in xs if rng.random() < 0.75]
        edges = [r.x0]
        for x in cuts:
            if x - edges[-1] >= lo:
                regions.append(_Region(Rect(x, y0, x + cw, y1), corridor=True))
                edges += [x, x + cw]
        edges.append(r.x1)
        for x0, x1 in zip(edges[0::2], edges[1::2]):
            if x1 - x0 > 1e-6:
                regions += [_Region(b) for b in _bsp(Rect(x0, y0, x1, y1), rng, lo, hi)]
    if transpose:
        regions = [_Region(Rect(g.rect.y0, g.rect.x0, g.rect.y1, g.rect.x1), g.corridor)
                   for g in regions]
    _carve_partition(canvas, regions, rng, cfg)


# ---------------------------------------------------------------------------- lattices


def _lattice(region: Rect, spacing: float) -> tuple[int, int, float, float]:
    nx = max(1, int(region.w // spacing))
    ny = max(1, int(region.h // spacing))
    return nx, ny, region.w / nx, region.h / ny


def _random_tree(nx: int, ny: int, rng: np.random.Generator, fraction: float = 1.0,
                 ) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Random spanning tree (randomised Prim) over a ``nx`` x ``ny`` lattice.

    Stops once ``fraction`` of the nodes are in the tree (a partial tree for sparse corridors).
    """
    start = (int(rng.integers(nx)), int(rng.integers(ny)))
    in_tree = {start}
    frontier = [(start, n) for n in _lattice_neighbours(start, nx, ny)]
    tree = []
    target = max(2, int(round(fraction * nx * ny)))
    while frontier and len(in_tree) < target:
        a, b = frontier.pop(int(rng.integers(len(frontier))))
        if b in in_tree:
            continue
        in_tree.add(b)
        tree.append((a, b))
        frontier += [(b, n) for n in _lattice_neighbours(b, nx, ny) if n not in in_tree]
    return tree


def _lattice_neighbours(node: tuple[int, int], nx: int, ny: int) -> list[tuple[int, int]]:
    i, j = node
    return [(a, b) for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))
            if 0 <= a < nx and 0 <= b < ny]


def carve_maze(canvas: Canvas, region: Rect, rng: np.random.Generator,
               cfg: GeneratorConfig) -> None:
    """A braided perfect maze: every cell reachable, a few walls removed to make loops."""
    nx, ny, sx, sy = _lattice(region, cfg.maze_cell)
    half = cfg.wall_thickness / 2

    def cell(i: int, j: int) -> Rect:
        return Rect(region.x0 + i * sx, region.y0 + j * sy, region.x0 + (i + 1) * sx,
                    region.y0 + (j + 1) * sy)

    for i in range(nx):
        for j in range(ny):
            canvas.carve(cell(i, j).inset(half))
    passages = set(_random_tree(nx, ny, rng))
    for i in range(nx):
        for j in range(ny):
            for n in ((i + 1, j), (i, j + 1)):
                if n[0] < nx and n[1] < ny and ((i, j), n) not in passages and (
                        n, (i, j)) not in passages and rng.random() < 0.06:
                    passages.add(((i, j), n))
    for a, b in passages:
        ra, rb = cell(*a), cell(*b)
        canvas.carve(Rect(min(ra.x0, rb.x0) + half, min(ra.y0, rb.y0) + half,
                          max(ra.x1, rb.x1) - half, max(ra.y1, rb.y1) - half)
                     if a[0] == b[0] else
                     Rect(min(ra.x0, rb.x0) + half, ra.y0 + half, max(ra.x1, rb.x1) - half,
                          ra.y1 - half))


def carve_corridor(canvas: Canvas, region: Rect, rng: np.random.Generator,
                   cfg: GeneratorConfig) -> None:
    """Narrow corridors along a random partial tree on a lattice (dead ends and turns)."""
    w = rng.uniform(*cfg.narrow_corridor_width)
    inner = region.inset(cfg.wall_thickness / 2)
    nx, ny, sx, sy = _lattice(Rect(0, 0, inner.w - w, inner.h - w), 3.0)
    nx, ny = nx + 1, ny + 1

    def centre(n: tuple[int, int]) -> tuple[float, float]:
        return inner.x0 + w / 2 + n[0] * sx, inner.y0 + w / 2 + n[1] * sy

    for a, b in _random_tree(nx, ny, rng, fraction=0.7):
        (xa, ya), (xb, yb) = centre(a), centre(b)
        canvas.carve(Rect(min(xa, xb) - w / 2, min(ya, yb) - w / 2, max(xa, xb) + w / 2,
                          max(ya, yb) + w / 2))


def carve_loop(canvas: Canvas, region: Rect, rng: np.random.Generator,
               cfg: GeneratorConfig) -> None:
    """A ring corridor round a solid core, maybe crossed, with dead-end side corridors."""
    half = cfg.wall_thickness / 2
    side = min(region.w, region.h)
    w = _fitted_width(rng.uniform(*cfg.loop_corridor_width), cfg.loop_corridor_width[0],
                      (side - 2.0 - cfg.wall_thickness) / 2)
    if w is None:
        min_side = 2 * cfg.loop_corridor_width[0] + 2.0 + cfg.wall_thickness
        raise UserInputError(f"loop needs at least {min_side:.1f} m on each side: make the "
                             "scene larger.")
    margin = half
    if side >= 14.0:
        margin = _uniform(rng, 2.0, min(4.5, side / 2 - w - 2.5))
    ring = region.inset(margin)
    for strip in (Rect(ring.x0, ring.y0, ring.x1, ring.y0 + w),
                  Rect(ring.x0, ring.y1 - w, ring.x1, ring.y1),
                  Rect(ring.x0, ring.y0, ring.x0 + w, ring.y1),
                  Rect(ring.x1 - w, ring.y0, ring.x1, ring.y1)):
        canvas.carve(strip)
    core = ring.inset(w)
    if rng.random() < 0.6 and min(core.w, core.h) > 2 * w + 2.0:
        if rng.random() < 0.5:
            x = _uniform(rng, core.x0 + 1.0, core.x1 - 1.0 - w)
            canvas.carve(Rect(x, core.y0 - 0.01, x + w, core.y1 + 0.01))
        else:
            y = _uniform(rng, core.y0 + 1.0, core.y1 - 1.0 - w)
            canvas.carve(Rect(core.x0 - 0.01, y, core.x1 + 0.01, y + w))
    outward = margin - half - cfg.wall_thickness
    for _ in range(int(rng.integers(1, 4))):
        side = int(rng.integers(4))
        horizontal_side = side < 2
        along = ((ring.x0 + w, ring.x1 - 2 * w) if horizontal_side
                 else (ring.y0 + w, ring.y1 - 2 * w))
        if along[1] <= along[0]:
            continue
        s = rng.uniform(*along)
        go_out = outward >= w + 0.5 and rng.random() < 0.6
        length = rng.uniform(w + 0.5, outward) if go_out else rng.uniform(
            1.5, max(1.6, (min(core.w, core.h)) / 2 - 0.5))
        sign = (-1 if side in (0, 2) else 1) * (1 if go_out else -1)
        edge = (ring.y0, ring.y1, ring.x0, ring.x1)[side]
        base = edge if go_out else edge - sign * w
        end = base + sign * length
        lo_, hi_ = sorted((base, end))
        spur = Rect(s, lo_, s + w, hi_) if horizontal_side else Rect(lo_, s, hi_, s + w)
        canvas.carve(spur)
        room = rng.uniform(2.5, 4.0)
        if not go_out and rng.random() < 0.5 and length > room:
            c = end - sign * room / 2
            cx, cy = (s + w / 2, c) if horizontal_side else (c, s + w / 2)
            canvas.carve(Rect(cx - room / 2, cy - room / 2, cx + room / 2, cy + room / 2))


def carve_hall(canvas: Canvas, region: Rect, rng: np.random.Generator,
               cfg: GeneratorConfig) -> None:
    """One open room with pillars and furniture-sized blocks at least 1 m apart."""
    inner = region.inset(cfg.wall_thickness / 2)
    canvas.carve(inner)
    placed: list[Rect] = []
    target = int(inner.w * inner.h / 12.0)
    for _ in range(40 * max(target, 1)):
        if len(placed) >= target:
            break
        sx, sy = (rng.uniform(0.3, 0.6),) * 2 if rng.random() < 0.5 else (
            rng.uniform(0.4, 1.6), rng.uniform(0.4, 0.8))
        if inner.x1 - 1.0 - sx < inner.x0 + 1.0 or inner.y1 - 1.0 - sy < inner.y0 + 1.0:
            continue  # No room for this block 1 m clear of the walls.
        x = rng.uniform(inner.x0 + 1.0, inner.x1 - 1.0 - sx)
        y = rng.uniform(inner.y0 + 1.0, inner.y1 - 1.0 - sy)
        r = Rect(x, y, x + sx, y + sy)
        if all(r.x1 + 1.0 < p.x0 or p.x1 + 1.0 < r.x0 or r.y1 + 1.0 < p.y0 or p.y1 + 1.0 < r.y0
               for p in placed):
            placed.append(r)
            canvas.fill(r)


def carve_labmaze(canvas: Canvas, region: Rect, rng: np.random.Generator,
                  cfg: GeneratorConfig) -> None:
    """Carves a labmaze maze into ``region``; labmaze's seed is drawn from ``rng``.

    Raises:
        UserInputError: the region holds fewer than 2 x 2 cells, or its passages would be
            too narrow for the robot.
    """
    lm = cfg.labmaze
    half = cfg.wall_thickness / 2
    nx, ny = int(region.w // lm.cell), int(region.h // lm.cell)
    if min(nx, ny) < 2:
        raise UserInputError(f"labmaze needs at least 2 x 2 cells of {lm.cell:g} m: make the "
                             f"scene (or its labmaze part, {region.w:.1f} x {region.h:.1f} m) "
                             "larger or the labmaze cell smaller.")
    sx, sy = region.w / nx, region.h / ny
    if min(sx, sy) - cfg.wall_thickness < 2 * TURTLEBOT3_WAFFLE.footprint_radius + 0.1:
        raise UserInputError(f"labmaze passages of {min(sx, sy) - cfg.wall_thickness:.2f} m are "
                             "too narrow for the robot: make the labmaze cell larger or the "
                             "walls thinner.")
    text = entity_layer(nx, ny, int(rng.integers(SEED_BOUND)), lm)
    rows, cols = canvas.solid.shape
    ex = text_edges(region.x0, sx, nx, half, canvas.resolution, cols)
    ey = text_edges(region.y0, sy, ny, half, canvas.resolution, rows)
    # The outer text ring is labmaze's boundary wall; the region's margin stands for it.
    free = (text != WALL)[::-1][1:-1, 1:-1]
    cells = np.repeat(np.repeat(free, np.diff(ey)[1:-1], axis=0), np.diff(ex)[1:-1], axis=1)
    canvas.solid[ey[1]:ey[-2], ex[1]:ex[-2]] &= ~cells


# ---------------------------------------------------------------------------- dungeon

DUNGEON_ROOM_MAX_SIDE = 10.0
"""Largest side of a ``dungeon`` room in metres (the smallest is ``room_size[0]``)."""
DUNGEON_ROOM_SPACING = 2.0
"""Least solid gap between two ``dungeon`` rooms in metres (corridors may cross it)."""
DUNGEON_MIN_WALL = 0.5
"""Walls that ``dungeon`` corridors leave thinner than this (metres) are opened, so that
corridors running side by side or along a room merge instead of leaving slivers."""
DUNGEON_PLACEMENT_TRIES = 10
"""``dungeon`` room placements tried per room of mean size that the region's area holds."""
DUNGEON_MIN_ROOMS = 3
"""``dungeon`` rooms wanted at least: a scatter with fewer is redrawn, up to
``DUNGEON_SCATTER_ROUNDS`` times (small areas may hold fewer; the fullest draw is kept)."""
DUNGEON_SCATTER_ROUNDS = 20
"""Room scatters drawn at most while fewer than ``DUNGEON_MIN_ROOMS`` rooms are placed."""
DUNGEON_EXTRA_CANDIDATES = 3
"""A ``dungeon`` room's nearest rooms (by centre) that may get an extra corridor to it."""


def _scatter_rooms(inner: Rect, rng: np.random.Generator, smallest: float, largest: float,
                   spacing: float) -> np.ndarray:
    """Rooms placed at random without overlap, a roguelike's first step.

    Every try draws the two sides uniformly from [``smallest``, ``largest``] and a uniform
    position inside ``inner``, and keeps the room if it stays ``spacing`` clear of the rooms
    kept so far. ``largest`` is capped so that two rooms fit side by side along each axis
    (but not below ``smallest``), so small areas still get several rooms.

    Args:
        inner: The carvable area, metres.
        rng: The source of every draw.
        smallest: Least room side, metres.
        largest: Greatest room side, metres.
        spacing: Least gap between two rooms, metres.

    Returns:
        (n, 4) array of rooms as x0, y0, x1, y1 in metres, in the order they were placed.
    """
    max_w, max_h = (min(largest, max(smallest, (side - spacing) / 2), side)
                    for side in (inner.w, inner.h))
    mean_area = (smallest + max_w) * (smallest + max_h) / 4
    tries = DUNGEON_PLACEMENT_TRIES * max(1, round(inner.w * inner.h / mean_area))
    rooms = np.empty((0, 4))
    for shrink in np.linspace(1.0, 0.0, tries):
        w = rng.uniform(smallest, smallest + shrink * (max_w - smallest))
        h = rng.uniform(smallest, smallest + shrink * (max_h - smallest))
        x0, y0 = rng.uniform(inner.x0, inner.x1 - w), rng.uniform(inner.y0, inner.y1 - h)
        clash = ((rooms[:, 0] < x0 + w + spacing) & (x0 < rooms[:, 2] + spacing)
                 & (rooms[:, 1] < y0 + h + spacing) & (y0 < rooms[:, 3] + spacing))
        if not clash.any():
            rooms = np.vstack([rooms, [x0, y0, x0 + w, y0 + h]])
    return rooms


def _room_links(centres: np.ndarray, rng: np.random.Generator, extra_probability: float,
                ) -> list[tuple[int, int]]:
    """Pairs of rooms to join: a minimum spanning tree of the centres, plus extra pairs.

    Each room's ``DUNGEON_EXTRA_CANDIDATES`` nearest rooms not already joined to it by the
    tree get a corridor with ``extra_probability`` each, which makes loops.

    Args:
        centres: (n, 2) room centres, metres.
        rng: The source of the extra pairs' draws.
        extra_probability: Chance of each extra pair.
    """
    n = len(centres)
    distance = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    in_tree = np.zeros(n, bool)
    in_tree[0] = True
    nearest_in_tree = distance[0].copy()
    parent = np.zeros(n, int)
    links = []
    for _ in range(n - 1):  # Prim's algorithm on the complete graph of room centres.
        j = int(np.argmin(np.where(in_tree, np.inf, nearest_in_tree)))
        links.append((int(parent[j]), j))
        in_tree[j] = True
        closer = distance[j] < nearest_in_tree
        parent[closer] = j
        nearest_in_tree = np.minimum(nearest_in_tree, distance[j])
    joined = {frozenset(link) for link in links}
    for i in range(n):
        for j in np.argsort(distance[i])[1:DUNGEON_EXTRA_CANDIDATES + 1]:
            pair = frozenset((i, int(j)))
            if pair not in joined and rng.random() < extra_probability:
                joined.add(pair)
                links.append((i, int(j)))
    return links


def _corridor_legs(a: np.ndarray, b: np.ndarray, width: float,
                   rng: np.random.Generator) -> list[Rect]:
    """The one or two rectangles of a corridor ``width`` wide from room ``a`` to room ``b``.

    Where the rooms face each other over at least ``width``, the corridor is straight;
    otherwise it is L-shaped, from a random point of ``a`` to a random point of ``b``,
    turning at either of the two corners (each equally likely). The points keep half the
    width from their room's walls, so the corridor opens fully into both rooms.

    Args:
        a: Room (x0, y0, x1, y1), metres.
        b: Room (x0, y0, x1, y1), metres.
        width: Corridor width, metres (at most every room side).
        rng: The source of the points and the turn.
    """
    half = width / 2
    pa = rng.uniform(a[:2] + half, a[2:] - half)
    pb = rng.uniform(b[:2] + half, b[2:] - half)
    overlap_lo, overlap_hi = np.maximum(a[:2], b[:2]), np.minimum(a[2:], b[2:])
    facing = overlap_hi - overlap_lo >= width
    if facing.any():
        axis = int(np.flatnonzero(facing)[rng.integers(facing.sum())])
        pa[axis] = pb[axis] = rng.uniform(overlap_lo[axis] + half, overlap_hi[axis] - half)
        stops = [pa, pb]
    else:
        turn = np.array([pb[0], pa[1]]) if rng.random() < 0.5 else np.array([pa[0], pb[1]])
        stops = [pa, turn, pb]
    return [Rect(min(p[0], q[0]) - half, min(p[1], q[1]) - half, max(p[0], q[0]) + half,
                 max(p[1], q[1]) + half) for p, q in zip(stops[:-1], stops[1:])]


def carve_dungeon(canvas: Canvas, region: Rect, rng: np.random.Generator,
                  cfg: GeneratorConfig) -> None:
    """A roguelike dungeon: scattered rooms joined by straight and L-shaped corridors.

    Rooms of ``cfg.room_size[0]`` to ``DUNGEON_ROOM_MAX_SIDE`` a side are placed at random,
    ``DUNGEON_ROOM_SPACING`` apart (redrawn while fewer than ``DUNGEON_MIN_ROOMS``).
    Corridors join them along a minimum spanning tree of their centres, plus extra corridors
    (``cfg.extra_door_probability``) that close loops; each corridor's width is drawn from
    ``cfg.loop_corridor_width`` and capped at half the narrower room's side (not below the
    range's minimum). Corridors may cross rooms and each other, as in the games; walls they
    leave thinner than ``DUNGEON_MIN_WALL`` (or ``cfg.wall_thickness`` if thicker) are opened.

    Raises:
        UserInputError: the region is narrower than the smallest room.
    """
    inner = region.inset(cfg.wall_thickness / 2)
    smallest = cfg.room_size[0]
    if min(inner.w, inner.h) < smallest:
        raise UserInputError(f"dungeon needs at least {smallest + cfg.wall_thickness:.1f} m on "
                             f"each side (its part is {region.w:.1f} x {region.h:.1f} m): make "
                             "the scene larger or the smallest room (room_size) smaller.")
    rooms = np.empty((0, 4))
    for _ in range(DUNGEON_SCATTER_ROUNDS):
        drawn = _scatter_rooms(inner, rng, smallest, max(smallest, DUNGEON_ROOM_MAX_SIDE),
                               DUNGEON_ROOM_SPACING)
        rooms = drawn if len(drawn) > len(rooms) else rooms
        if len(rooms) >= DUNGEON_MIN_ROOMS:
            break
    for x0, y0, x1, y1 in rooms:
        canvas.carve(Rect(x0, y0, x1, y1))
    centres = (rooms[:, :2] + rooms[:, 2:]) / 2
    sides = rooms[:, 2:] - rooms[:, :2]
    narrowest = cfg.loop_corridor_width[0]
    for i, j in _room_links(centres, rng, cfg.extra_door_probability):
        # At most half the narrower room's side, so that corridors stay narrower than rooms.
        side = sides[[i, j]].min()
        width = min(rng.uniform(*cfg.loop_corridor_width), max(narrowest, side / 2), side)
        for leg in _corridor_legs(rooms[i], rooms[j], width, rng):
            canvas.carve(leg)
    window = canvas._cells(inner)
    wall_cells = max(1, round(max(DUNGEON_MIN_WALL, cfg.wall_thickness) / canvas.resolution))
    # Outside the window lies this region's solid margin, hence border_value=True.
    canvas.solid[window] = ndimage.binary_opening(
        canvas.solid[window], structure=np.ones((wall_cells, wall_cells), bool),
        border_value=True)


FAMILIES: dict[str, Callable[[Canvas, Rect, np.random.Generator, GeneratorConfig], None]] = {
    "office": carve_office,
    "rooms": carve_rooms,
    "maze": carve_maze,
    "loop": carve_loop,
    "corridor": carve_corridor,
    "hall": carve_hall,
    "labmaze": carve_labmaze,
    "dungeon": carve_dungeon,
}


def parse_family(family: str) -> list[str]:
    """Splits ``'loop+rooms'`` into known family names.

    Raises:
        UserInputError: an unknown family name.
    """
    parts = [p.strip() for p in family.split("+")]
    unknown = [p for p in parts if p not in FAMILIES]
    if unknown or not parts:
        raise UserInputError(f"unknown scene family {family!r}: use one of "
                             f"{', '.join(sorted(FAMILIES))}, or several joined by '+' "
                             "(e.g. loop+rooms).")
    return parts


def _join_parts(canvas: Canvas, x_split: float, y0: float, y1: float,
                rng: np.random.Generator, cfg: GeneratorConfig,
                targets: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Cuts a passage across the vertical wall at ``x_split`` between two parts.

    Picks a band of rows (one door width) where free space lies within a reach on both
    sides of the wall and carves straight through to it; the reach grows (4, 8, 16, 32 m)
    until such a band exists. ``targets``: (left, right) masks of the only cells that count
    as free on each side.
    """
    for reach in (4.0, 8.0, 16.0, 32.0):
        if _join_parts_within(canvas, x_split, y0, y1, rng, cfg, reach, targets):
            return


def _join_parts_within(canvas: Canvas, x_split: float, y0: float, y1: float,
                       rng: np.random.Generator, cfg: GeneratorConfig, reach: float,
                       targets: tuple[np.ndarray, np.ndarray] | None) -> bool:
    res = canvas.resolution
    free_l, free_r = (~canvas.solid,) * 2 if targets is None else targets
    xs = round(x_split / res)
    k = round(reach / res)
    r0, r1 = round((y0 + 1.0) / res), round((y1 - 1.0) / res)
    if r1 <= r0:
        return False
    left = free_l[r0:r1, max(xs - k, 0):xs][:, ::-1]
    right = free_r[r0:r1, xs:xs + k]
    has_l, has_r = left.any(axis=1), right.any(axis=1)
    dist_l = np.where(has_l, left.argmax(axis=1), k)
    dist_r = np.where(has_r, right.argmax(axis=1), k)
    ok = has_l & has_r
    band = max(1, round(np.mean(cfg.door_width) / res))
    window_ok = np.convolve(ok.astype(int), np.ones(band, int), mode="valid") == band
    starts = np.flatnonzero(window_ok)
    if len(starts) == 0:
        return False
    s = int(starts[rng.integers(len(starts))])
    dl, dr = int(dist_l[s:s + band].max()), int(dist_r[s:s + band].max())
    canvas.solid[r0 + s:r0 + s + band, xs - dl:xs + dr] = False
    return True


def _footprint_regions(solid: np.ndarray, resolution: float) -> np.ndarray:
    """Labels of the connected regions the robot's footprint centre can move through."""
    fits = clearance(~solid, resolution) > TURTLEBOT3_WAFFLE.footprint_radius
    return ndimage.label(fits, structure=np.ones((3, 3)))[0]


def _main_regions(labels: np.ndarray, cols: np.ndarray) -> list[np.ndarray]:
    """Per part (columns ``cols[i]:cols[i + 1]``), its largest footprint region's cells."""
    masks = []
    for c0, c1 in zip(cols[:-1], cols[1:]):
        counts = np.bincount(labels[:, c0:c1].ravel())
        counts[0] = 0
        mask = np.zeros(labels.shape, bool)
        mask[:, c0:c1] = labels[:, c0:c1] == np.argmax(counts) if counts.any() else False
        masks.append(mask)
    return masks


def _reconnect_parts(canvas: Canvas, bounds: np.ndarray, mains: list[np.ndarray],
                     area: Rect, rng: np.random.Generator, cfg: GeneratorConfig) -> None:
    """Joins neighbouring parts whose main regions (``mains``, as carved, before the
    joins) the joins left apart: a join can reach a pocket of the next part, or a stub
    of the previous one reaching into it, instead of its main region."""
    for i, x in enumerate(bounds[1:-1]):
        labels = _footprint_regions(canvas.solid, canvas.resolution)
        ids = [np.bincount(labels[m]).argmax() if m.any() else 0 for m in mains[i:i + 2]]
        if ids[0] != ids[1] and min(ids) > 0:
            _join_parts(canvas, float(x), area.y0, area.y1, rng, cfg,
                        targets=(labels == ids[0], labels == ids[1]))


def generate_solid(family: str, width: float, height: float, resolution: float,
                   rng: np.random.Generator, cfg: GeneratorConfig) -> np.ndarray:
    """Generates the wall grid of a scene (before validation).

    Args:
        family: A family name or several joined by '+'.
        width: Size along x in metres, outer walls included.
        height: Size along y in metres.
        resolution: Cell side in metres.
        rng: The only source of randomness.
        cfg: Generator dimensions.

    Returns:
        Boolean array (rows, cols), True for wall cells; row 0 at y = 0.
    """
    parts = parse_family(family)
    canvas = Canvas(width, height, resolution)
    half = cfg.wall_thickness / 2
    area = Rect(half, half, width - half, height - half)
    transpose = area.h > area.w and len(parts) > 1
    if transpose:
        canvas.solid = canvas.solid.T.copy()
        area = Rect(area.y0, area.x0, area.y1, area.x1)
    if len(parts) == 1:
        FAMILIES[parts[0]](canvas, area, rng, cfg)
    else:
        weights = rng.uniform(0.8, 1.2, size=len(parts))
        bounds = area.x0 + np.concatenate([[0], np.cumsum(weights) / weights.sum()]) * area.w
        bounds = np.round(bounds / resolution) * resolution
        for name, x0, x1 in zip(parts, bounds[:-1], bounds[1:]):
            FAMILIES[name](canvas, Rect(float(x0), area.y0, float(x1), area.y1), rng, cfg)
        carved = canvas.solid.copy()  # The parts before they are joined.
        for x in bounds[1:-1]:
            _join_parts(canvas, float(x), area.y0, area.y1, rng, cfg)
            if rng.random() < 0.5:
                _join_parts(canvas, float(x), area.y0, area.y1, rng, cfg)
        if unreachable_share(_closed(canvas.solid.copy(), cfg, resolution), resolution) > \
                MAX_UNREACHABLE_SHARE:
            mains = _main_regions(_footprint_regions(carved, resolution),
                                  np.round(bounds / resolution).astype(int))
            _reconnect_parts(canvas, bounds, mains, area, rng, cfg)
    return _closed(canvas.solid.T.copy() if transpose else canvas.solid, cfg, resolution)


def _closed(solid: np.ndarray, cfg: GeneratorConfig, resolution: float) -> np.ndarray:
    """``solid`` with its outer wall closed, whatever a generator carved (in place)."""
    t = max(1, round(cfg.wall_thickness / resolution))
    solid[:t // 2 or 1, :] = solid[-(t // 2 or 1):, :] = True
    solid[:, :t // 2 or 1] = solid[:, -(t // 2 or 1):] = True
    return solid
