"""Shared fixtures: paths and small hand-built scenes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.scenes.importer import scene_from_grid
from mjexplore.scenes.scene import write_scene

# `make test` runs the same examples every time (no flaky reds in CI); hunt for new failing
# examples with `pytest --hypothesis-profile explore` (add those found as @example cases).
settings.register_profile("repeatable", derandomize=True, deadline=None)
settings.register_profile("explore", deadline=None)
settings.load_profile("repeatable")

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MJEXPLORE_SHARED", REPO.parent / "shared"))


def shared_data(*parts: str) -> Path:
    path = SHARED.joinpath("data", *parts)
    if not path.exists():
        pytest.skip(f"reference data {path} is not present (it lives in shared/ beside the repo)")
    return path


def box_room_grid(inner_w: float = 6.0, inner_h: float = 4.0, wall: float = 0.2,
                  res: float = 0.05) -> tuple[GridMap, tuple[float, float, float, float]]:
    """A rectangular room: returns the grid and the interior (x0, y0, x1, y1) in metres."""
    cols = round((inner_w + 2 * wall) / res)
    rows = round((inner_h + 2 * wall) / res)
    k = round(wall / res)
    data = np.full((rows, cols), OCCUPIED, np.int8)
    data[k:rows - k, k:cols - k] = FREE
    return GridMap(data, res, (0.0, 0.0, 0.0)), (wall, wall, wall + inner_w, wall + inner_h)


@pytest.fixture(scope="session")
def box_room(tmp_path_factory) -> tuple[Path, tuple[float, float, float, float]]:
    """A 6 x 4 m box room scene folder and its interior rectangle."""
    grid, interior = box_room_grid()
    out = tmp_path_factory.mktemp("box_room") / "scene"
    write_scene(scene_from_grid(grid, "box_room", {"source": "test"},
                                start=(1.0, 2.2, 0.0)), out)
    return out, interior


def random_tree(rng: np.random.Generator, n: int, k: int, real: int) -> np.ndarray:
    """(n, k) neighbour slots of a random tree over the first ``real`` nodes (symmetric,
    at most k per node), -1 elsewhere: a well-formed TER adjacency for policy tests."""
    neigh = np.full((n, k), -1.0, np.float32)
    fill = np.zeros(n, int)
    for i in range(1, real):
        j = int(rng.integers(0, i))
        if fill[i] < k and fill[j] < k:
            neigh[i, fill[i]], neigh[j, fill[j]] = j, i
            fill[i] += 1
            fill[j] += 1
    return neigh
