"""Goals given up on, and when to try them again.

A goal is given up (blacklisted) when no path to it exists, when the robot stops getting
closer along its path, when the robot lingers on the way, or when the robot stood at it and
its frontier stayed open. None of these need be final: a path may open, a wedge may clear, a
new view may show the way. So an entry is *forgotten* once the map around it has changed
(``forget_area`` of newly known space within ``forget_radius``), and the entries given up
for want of a path or of progress are *offered again* (:meth:`GoalBlacklist.reoffer`) when
nothing else is left, up to ``max_attempts`` times while the map around them stays as it
was. An entry the robot reached without its frontier closing watches only its own
surroundings (``seen_area`` within ``radius``): standing there again would show nothing new
unless the map right there changed, and the space further off that the robot saw on its way
is no reason to come back.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from mjexplore.maps import GridMap

REASONS = ("no_path", "no_progress", "lingered", "seen_open")
# Reasons that say "could not get there" rather than "got there, saw nothing more".
_RETRYABLE = ("no_path", "no_progress", "lingered")


@dataclasses.dataclass(frozen=True, kw_only=True)
class BlacklistConfig:
    """Blacklist settings (metres, square metres).

    Attributes:
        radius: Goals within this distance of an active entry are out.
        forget_radius: Radius of the window around an entry whose map is watched.
        forget_area: An entry is forgotten once this much space in its window has become
            known since it was added.
        seen_area: An entry whose goal was reached with its frontier open is forgotten once
            this much space within ``radius`` of it has become known.
        max_attempts: How often a goal may be given up while the map around it stays
            unchanged before :meth:`GoalBlacklist.reoffer` stops offering it.
    """

    radius: float = 0.5
    forget_radius: float = 1.5
    forget_area: float = 0.25
    seen_area: float = 0.05
    max_attempts: int = 3

    def __post_init__(self) -> None:
        if self.radius <= 0 or min(self.forget_radius, self.forget_area, self.seen_area) <= 0 \
                or self.max_attempts < 1:
            raise ValueError("radius, forget_radius, forget_area and seen_area must be > 0, "
                             "max_attempts >= 1")


@numba.njit(cache=True)
def _count_known(data, r0, r1, c0, c1):
    out = np.zeros(len(r0), np.int64)
    for i in range(len(r0)):
        for r in range(r0[i], r1[i]):
            for c in range(c0[i], c1[i]):
                if data[r, c] >= 0:
                    out[i] += 1
    return out


def known_in_windows(data: np.ndarray, cells: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Known cells (value >= 0) of the map ``data`` in ``data[max(r - k, 0):r + k + 1,
    max(c - k, 0):c + k + 1]`` for each (r, c) of ``cells`` (k, 2) and k of ``half`` (k,),
    with numpy's slicing (clipped to the map; a negative end counts from the far side)."""
    rows, cols = data.shape

    def bounds(centre, size):
        start = np.minimum(np.maximum(centre - half, 0), size)
        stop = centre + half + 1
        stop = np.where(stop < 0, np.maximum(stop + size, 0), np.minimum(stop, size))
        return start, np.maximum(stop, start)

    r0, r1 = bounds(cells[:, 0], rows)
    c0, c1 = bounds(cells[:, 1], cols)
    return _count_known(data, r0, r1, c0, c1)


@dataclasses.dataclass
class _Entry:
    point: np.ndarray
    reason: str
    known_cells: int
    attempts: int = 1
    active: bool = True


class GoalBlacklist:
    """The goals an episode gave up on (see the module docstring).

    Args:
        config: Blacklist settings.
    """

    def __init__(self, config: BlacklistConfig | None = None) -> None:
        self.config = config or BlacklistConfig()
        self._entries: list[_Entry] = []

    def __len__(self) -> int:
        return sum(e.active for e in self._entries)

    def points(self) -> np.ndarray:
        """(k, 2) active entries, metres in the ``map`` frame."""
        return np.array([e.point for e in self._entries if e.active]).reshape(-1, 2)

    def reasons(self) -> dict[str, int]:
        """How many active entries each reason holds."""
        return {r: sum(e.active and e.reason == r for e in self._entries) for r in REASONS}

    def _watch(self, reason: str) -> tuple[float, float]:
        """(window radius in metres, newly known area in square metres) that forgets an
        entry given up for ``reason``."""
        cfg = self.config
        if reason == "seen_open":
            return cfg.radius, cfg.seen_area
        return cfg.forget_radius, cfg.forget_area

    def _known_cells(self, grid: GridMap, points: np.ndarray, reasons: list[str]) -> np.ndarray:
        """Known cells in the watched window of each (x, y) of ``points`` (k, 2) given up
        for the reason of the same index: the square of half-side the watch radius in cells
        (at least 1) around the point's cell, clipped to the map."""
        cells = grid.world_to_cell(np.asarray(points, float).reshape(-1, 2))
        half = np.array([max(1, int(round(self._watch(r)[0] / grid.resolution)))
                         for r in reasons], np.int64)
        return known_in_windows(grid.data, cells, half)

    def add(self, point: np.ndarray, reason: str, grid: GridMap) -> None:
        """Gives up the goal ``point`` (x, y) for ``reason`` on the map ``grid``.

        A goal within ``radius`` of an earlier entry renews that entry and counts one more
        attempt.
        """
        if reason not in REASONS:
            raise ValueError(f"reason must be one of {REASONS}")
        point = np.asarray(point, float)[:2].copy()
        known = int(self._known_cells(grid, point, [reason])[0])
        for e in self._entries:
            if np.hypot(*(e.point - point)) <= self.config.radius:
                # The first point stays: a renewed entry must not creep away from the
                # goals it already covers.
                e.reason, e.known_cells, e.active = reason, known, True
                e.attempts += 1
                return
        self._entries.append(_Entry(point, reason, known))

    def forget_changed(self, grid: GridMap) -> int:
        """Forgets the entries whose surroundings changed; returns how many."""
        cell_area = grid.resolution ** 2
        forgotten = 0
        if not self._entries:
            return 0
        known = self._known_cells(grid, np.array([e.point for e in self._entries]),
                                  [e.reason for e in self._entries])
        for e, now in zip(self._entries, known.tolist()):
            if (now - e.known_cells) * cell_area >= self._watch(e.reason)[1]:
                forgotten += e.active
                e.attempts = 0  # A changed map: a fresh start, no attempts to remember.
        self._entries = [e for e in self._entries if e.attempts > 0]
        return forgotten

    def reoffer(self) -> int:
        """Lifts the entries given up for want of a path or of progress that have attempts
        left; returns how many (0: nothing left to try again)."""
        lifted = 0
        for e in self._entries:
            if e.active and e.reason in _RETRYABLE and e.attempts < self.config.max_attempts:
                e.active = False
                lifted += 1
        return lifted
