"""The ``labmaze`` scene family: DeepMind Lab's random mazes, rooms joined by corridors.

`labmaze <https://github.com/google-deepmind/labmaze>`_ is DeepMind Lab's text-maze
generator, the one dm_control.locomotion's maze arenas use. Its entity layer is a text grid
of odd size ``2n + 1``: odd rows and columns hold the maze's cells, even ones the walls
between them; ``'*'`` is wall and every other character is free (``' '`` and ``'.'``, and
the spawn ``'P'`` and object ``'G'`` tokens, which this family does not ask for).

The grid becomes metres the way the ``maze`` family lays out its lattice: the region is
split into ``nx x ny`` cells of about :attr:`LabmazeConfig.cell` metres (stretched to fill
it); an odd text column is a cell's interior (the pitch less one wall thickness) and an even
one the wall line between two cells (``wall_thickness`` wide). So passages are
``cell - wall_thickness`` wide (1.35 m by default: the paper's mazes have 1-1.5 m
corridors; the Turtlebot3 Waffle's footprint is 0.52 m across), rooms are open areas
several cells wide, and walls are as thin as in the other families instead of one text
character (dm_control's ``xy_scale``, 2 m) thick. Text row 0 is the region's north (top)
edge, as the text reads and as ``preview.png`` shows it.
"""

from __future__ import annotations

import dataclasses

import labmaze
import numpy as np

from mjexplore.errors import UserInputError

WALL = "*"
SEED_BOUND = 2**31  # labmaze's random_seed is a 31-bit integer.


@dataclasses.dataclass(frozen=True, kw_only=True)
class LabmazeConfig:
    """labmaze's knobs for the ``labmaze`` family (lengths in metres).

    Attributes:
        cell: Pitch of the maze lattice in metres: one passage plus one wall. 1.5 m with
            0.15 m walls gives 1.35 m corridors.
        max_rooms: Most rooms labmaze places (it places fewer where they do not fit within
            ``retry_count`` tries). None: one per ``cells_per_room`` lattice cells, at least
            two (with ``simplify``, a single room loses every corridor).
        cells_per_room: Lattice cells per room when ``max_rooms`` is None.
        room_cells: (min, max) side of a room in lattice cells (2 and 3: 2.85-4.35 m rooms
            at the default pitch); labmaze's ``room_min_size`` / ``room_max_size`` are
            ``2 n - 1`` text characters, clipped to the maze.
        extra_connection_probability: labmaze's chance of a further opening between
            neighbouring rooms and corridors (0: a tree of rooms and corridors, no loops).
        simplify: labmaze's ``simplify``: fill dead-end corridors, leaving rooms and the
            corridors that join them (with some solid blocks between).
        retry_count: labmaze's tries at placing each room.
    """

    cell: float = 1.5
    max_rooms: int | None = None
    cells_per_room: float = 16.0
    room_cells: tuple[int, int] = (2, 3)
    extra_connection_probability: float = 0.1
    simplify: bool = True
    retry_count: int = 1000

    def __post_init__(self) -> None:
        if not 1.0 <= self.cell <= 10.0:
            raise UserInputError(f"labmaze cell {self.cell} m is out of range: use 1.0 to 10.0 m "
                                 "(passage width plus one wall).")
        if self.max_rooms is not None and self.max_rooms < 1:
            raise UserInputError(f"labmaze max_rooms {self.max_rooms} must be at least 1 (or "
                                 "None to scale with the area).")
        if not self.cells_per_room > 0:
            raise UserInputError(f"labmaze cells_per_room {self.cells_per_room} must be positive.")
        lo, hi = self.room_cells
        if not 2 <= lo <= hi:
            raise UserInputError(f"labmaze room_cells {self.room_cells} must be (min, max) with "
                                 "2 <= min <= max lattice cells.")
        if not 0.0 <= self.extra_connection_probability <= 1.0:
            raise UserInputError("labmaze extra_connection_probability "
                                 f"{self.extra_connection_probability} must be from 0 to 1.")
        if self.retry_count < 1:
            raise UserInputError(f"labmaze retry_count {self.retry_count} must be at least 1.")


def entity_layer(nx: int, ny: int, seed: int, cfg: LabmazeConfig) -> np.ndarray:
    """labmaze's entity layer for an ``nx x ny`` lattice of cells.

    Args:
        nx: Cells along x (at least 2).
        ny: Cells along y (at least 2).
        seed: labmaze's ``random_seed``, 0 <= seed < 2**31.
        cfg: The family's knobs.

    Returns:
        Array of single characters, shape (2 ny + 1, 2 nx + 1); row 0 is the north edge.
    """
    size = 2 * min(nx, ny) - 1  # The largest room that fits inside the outer wall.
    rooms = cfg.max_rooms or max(2, round(nx * ny / cfg.cells_per_room))
    maze = labmaze.RandomMaze(
        height=2 * ny + 1, width=2 * nx + 1, max_rooms=rooms,
        room_min_size=min(2 * cfg.room_cells[0] - 1, size),
        room_max_size=min(2 * cfg.room_cells[1] - 1, size),
        retry_count=cfg.retry_count,
        extra_connection_probability=cfg.extra_connection_probability,
        simplify=cfg.simplify, random_seed=int(seed))
    return np.asarray(maze.entity_layer)


def text_edges(start: float, pitch: float, n: int, half: float, resolution: float,
                limit: int) -> np.ndarray:
    """Grid-cell edges of the ``2 n + 1`` text columns (or rows) laid along one axis.

    Even text index ``2 k`` is the wall line at ``start + k * pitch`` (``2 half`` wide), odd
    ``2 k + 1`` the cell interior after it; edges snap to the grid as ``Canvas.carve`` does.

    Returns:
        int array of ``2 n + 2`` edges, clipped to ``[0, limit]``.
    """
    lines = start + np.arange(n + 1) * pitch
    metres = np.stack([lines - half, lines + half], axis=1).ravel()
    return np.clip(np.round(metres / resolution).astype(int), 0, limit)
