"""Covering the occupied cells of a grid with few axis-aligned rectangles.

Walls become MuJoCo boxes; lidar ray cost grows with the number of geoms, so a wall that
is 3 cells thick and 200 cells long must be one box, not 600.
"""

from __future__ import annotations

import numpy as np


def _row_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, start_col, end_col_exclusive) of every horizontal run of True cells, row-sorted."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    step = np.diff(padded, axis=1)
    rows, starts = np.nonzero(step == 1)
    _, ends = np.nonzero(step == -1)
    return rows, starts, ends


def _merge_runs(mask: np.ndarray) -> np.ndarray:
    """Stacks identical runs on consecutive rows into rectangles [r0, c0, r1, c1) (exclusive)."""
    rows, starts, ends = _row_runs(mask)
    rects: list[tuple[int, int, int, int]] = []
    open_rects: dict[tuple[int, int], tuple[int, int]] = {}  # (c0, c1) -> (first, last row)
    for r, c0, c1 in zip(rows.tolist(), starts.tolist(), ends.tolist()):
        key = (c0, c1)
        entry = open_rects.get(key)
        if entry is not None and entry[1] == r - 1:
            open_rects[key] = (entry[0], r)
            continue
        if entry is not None:
            rects.append((entry[0], c0, entry[1] + 1, c1))
        open_rects[key] = (r, r)
    rects.extend((r0, c0, r1 + 1, c1) for (c0, c1), (r0, r1) in open_rects.items())
    return np.asarray(sorted(rects), dtype=np.int64).reshape(-1, 4)


def cover_rectangles(mask: np.ndarray) -> np.ndarray:
    """Covers the True cells of ``mask`` exactly with disjoint axis-aligned rectangles.

    Runs of cells are merged along rows and then stacked; the same is done with columns,
    and the cover with fewer rectangles is returned.

    Args:
        mask: 2D boolean array.

    Returns:
        int array (n, 4) of [row0, col0, row1, col1) rectangles (end indices exclusive).
    """
    mask = np.asarray(mask, dtype=bool)
    by_rows = _merge_runs(mask)
    by_cols = _merge_runs(mask.T)[:, [1, 0, 3, 2]]
    return by_rows if len(by_rows) <= len(by_cols) else np.asarray(sorted(map(tuple, by_cols)),
                                                                    dtype=np.int64).reshape(-1, 4)


def rasterize_rectangles(rects: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`cover_rectangles`: a boolean mask with the rectangles' cells set."""
    mask = np.zeros(shape, dtype=bool)
    for r0, c0, r1, c1 in np.asarray(rects, dtype=np.int64).reshape(-1, 4):
        mask[r0:r1, c0:c1] = True
    return mask
