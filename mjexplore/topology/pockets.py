"""Which frontiers lead to almost nothing: a learned predictor of the pocket behind one.

About half the frontiers of a partial indoor map open onto a pocket of unseen free space
smaller than half a square metre: the corner behind a door leaf, the strip behind a wall
end, grazing gaps. Nearest-frontier drives to each of them in turn, while an explorer that
passes over them still reaches the episode's target ratio (the lidar sees them on the way
to other goals, or they stay within what the target leaves unseen). Knowing the pocket's
size is most of what the ground-truth oracle knows: on 16 generated layouts
nearest-frontier that skips frontiers whose *true* pocket is below 0.5 m^2 explores in
0.78 x nearest's time, the oracle in 0.72 x (``python -m tools.research.pocket_headroom``).

The true pocket of a frontier (:func:`pocket_areas`: the unexplored free space of the
ground truth connected to it, the paper's information gain in m^2) needs the ground truth.
:class:`PocketNet` predicts from the partial map alone whether it is small: its input is a
6.4 m square patch of the map around the frontier (:func:`frontier_patches`: free and
occupied shares and the frontier's own cells, resampled to 0.1 m cells whatever the map's
resolution), and the frontier's length. It is trained on patches and true pockets from
generated layouts (:mod:`mjexplore.learning.pocket_training`), and :class:`PocketPredictor`
serves it to the decision space, which gives each TER frontier node the probability as a feature.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.io.provenance import REPO, file_sha256
from mjexplore.io.tensor_file import read_tensor_file
from mjexplore.maps import GridMap
from mjexplore.topology.frontiers import Frontier, information_gain
from mjexplore.topology.ter import FRONTIER_FLAG, PaddedTer

PATCH_CELLS = 64  # Patch side, cells.
PATCH_RESOLUTION = 0.1  # Patch cell side, metres (a 6.4 m square).
PATCH_CHANNELS = ("free", "occupied", "frontier")
FORMAT = "mjexplore-pockets-v1"


def frontier_windows(grid: GridMap, frontiers: list[Frontier]
                     ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The map around each frontier at its own resolution, what :func:`frontier_patches`
    resamples.

    Returns:
        Per frontier: int8 (side, side) classes of the map's cells in the square of
        ``PATCH_CELLS * PATCH_RESOLUTION`` metres centred on the mean of the frontier's
        cells (-1 unknown or outside the map, 0 free, 1 occupied; rows along +y), and the
        frontier's cells (k, 2) in that square's (row, col) (some may lie outside it).
    """
    side = max(1, int(round(PATCH_CELLS * PATCH_RESOLUTION / grid.resolution)))
    half = side // 2
    data = grid.data
    rows, cols = data.shape
    out = []
    for f in frontiers:
        r0, c0 = np.round(f.cells.mean(axis=0)).astype(int) - half
        window = np.full((side, side), -1, np.int8)
        a0, a1 = max(r0, 0), min(r0 + side, rows)
        b0, b1 = max(c0, 0), min(c0 + side, cols)
        if a0 < a1 and b0 < b1:
            np.sign(data[a0:a1, b0:b1], out=window[a0 - r0:a1 - r0, b0 - c0:b1 - c0])
        out.append((window, f.cells - (r0, c0)))
    return out


def window_patch(window: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The patch (uint8 (3, PATCH_CELLS, PATCH_CELLS)) of one of :func:`frontier_windows`'
    windows and frontier cells."""
    side = len(window)
    layers = np.zeros((3, side, side), np.float32)  # Free, occupied, the frontier's cells.
    layers[0] = window == 0
    layers[1] = window > 0
    inside = ((cells >= 0) & (cells < side)).all(axis=1)
    layers[2, cells[inside, 0], cells[inside, 1]] = 1.0
    out = np.empty((3, PATCH_CELLS, PATCH_CELLS), np.uint8)
    for k, layer in enumerate(layers):
        resized = layer if side == PATCH_CELLS else cv2.resize(
            layer, (PATCH_CELLS, PATCH_CELLS), interpolation=cv2.INTER_AREA)
        out[k] = np.round(np.clip(resized, 0.0, 1.0) * 255.0)
    return out


def frontier_patches(grid: GridMap, frontiers: list[Frontier]) -> np.ndarray:
    """Map patches centred on each frontier's cells, at ``PATCH_RESOLUTION``.

    Each patch covers ``PATCH_CELLS * PATCH_RESOLUTION`` metres a side around the mean of
    the frontier's cells, axis-aligned with the map (rows along +y); outside the map reads
    as unknown. Channels (``PATCH_CHANNELS``): the share of free cells, of occupied cells
    and of the frontier's own cells in each patch cell (area resampling), times 255.

    Returns:
        uint8 (n, 3, PATCH_CELLS, PATCH_CELLS).
    """
    out = np.zeros((len(frontiers), len(PATCH_CHANNELS), PATCH_CELLS, PATCH_CELLS), np.uint8)
    for i, (window, cells) in enumerate(frontier_windows(grid, frontiers)):
        out[i] = window_patch(window, cells)
    return out


def frontier_lengths(grid: GridMap, frontiers: list[Frontier]) -> np.ndarray:
    """Each frontier's length, metres (its cell count times the cell side)."""
    return np.array([f.size * grid.resolution for f in frontiers], np.float32)


def pocket_areas(grid: GridMap, ground_truth: GridMap, frontiers: list[Frontier]) -> np.ndarray:
    """The true pocket of each frontier, m^2: the unexplored free space of the ground truth
    8-connected to it (:func:`~mjexplore.topology.frontiers.information_gain` in area)."""
    total = float(ground_truth.free.sum()) * ground_truth.resolution ** 2
    return information_gain(grid, ground_truth, frontiers) * total


def node_frontiers(padded: PaddedTer, grid: GridMap,
                   frontiers: list[Frontier]) -> tuple[np.ndarray, np.ndarray]:
    """The TER's frontier nodes and the frontier each stands for (a node sits at its
    frontier's goal cell; the first frontier of a shared goal cell).

    Returns:
        (k,) node indices of ``padded`` and (k,) indices into ``frontiers``.
    """
    nodes = np.flatnonzero((padded.node_mask > 0) & (padded.node_features[:, 5] == FRONTIER_FLAG))
    index = {tuple(f.goal_cell): i for i, f in reversed(list(enumerate(frontiers)))}
    cells = grid.world_to_cell(padded.node_positions[nodes].astype(float))
    matched = [(n, index.get((int(r), int(c)))) for n, (r, c) in zip(nodes, cells)]
    matched = [(n, i) for n, i in matched if i is not None]
    return (np.array([n for n, _ in matched], np.int64),
            np.array([i for _, i in matched], np.int64))


class PocketNet(nn.Module):
    """Patch and frontier length -> logit that the frontier's pocket is small.

    Four strided convolutions (64 -> 4 cells), then two linear layers with the log of the
    frontier's length in patch cells beside the convolutional features.
    """

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(len(PATCH_CHANNELS), 16, 5, 2, 2), nn.ReLU(),
            nn.Conv2d(16, 32, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(32, 64, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(64, 64, 3, 2, 1), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(64 * (PATCH_CELLS // 16) ** 2 + 1, 64), nn.ReLU(),
                                  nn.Linear(64, 1))

    def forward(self, patches: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """Logits (B,) of uint8 or [0, 255] float patches (B, 3, S, S) and lengths (B,) m."""
        x = patches.to(torch.float32) / 255.0
        h = self.conv(x).flatten(1)
        length = torch.log1p(lengths.to(torch.float32) / PATCH_RESOLUTION)
        return self.head(torch.cat([h, length[:, None]], 1))[:, 0]


def save_pocket_net(path: str | os.PathLike, net: PocketNet, small_area_m2: float,
                    provenance: dict | None = None) -> None:
    """Writes the predictor's weights and what they predict (safetensors, atomically)."""
    from safetensors.torch import save

    tensors = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    meta = {"format": FORMAT, "small_area_m2": repr(float(small_area_m2)),
            "patch": json.dumps({"cells": PATCH_CELLS, "resolution": PATCH_RESOLUTION,
                                 "channels": PATCH_CHANNELS}),
            "provenance": json.dumps(provenance or {}, default=str)}
    write_bytes_atomic(path, save(tensors, metadata=meta))


class PocketPredictor:
    """A trained :class:`PocketNet` from its weights file, for inference.

    Args:
        path: A file written by :func:`save_pocket_net` (``mjexplore train-pockets``).

    Raises:
        UserInputError: unreadable, not a pocket predictor, or for another patch layout.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        hint = ("give the file 'mjexplore train-pockets' wrote (e.g. "
                "training/pockets.safetensors).")
        tensors, meta = read_tensor_file(self.path, "the pocket predictor", hint)
        patch = {"cells": PATCH_CELLS, "resolution": PATCH_RESOLUTION,
                 "channels": list(PATCH_CHANNELS)}
        try:
            ours = meta.get("format") == FORMAT and json.loads(meta.get("patch", "{}")) == patch
            self.small_area_m2 = float(meta["small_area_m2"]) if ours else 0.0
            self.provenance = json.loads(meta.get("provenance", "{}")) if ours else {}
        except (KeyError, TypeError, ValueError):
            ours = False
        if not ours:
            raise UserInputError(f"{str(path)!r} is not a pocket predictor of this version "
                                 f"(format {meta.get('format')!r}); {hint}")
        self.net = PocketNet()
        try:
            self.net.load_state_dict(tensors)
        except RuntimeError as exc:
            raise UserInputError(f"weights in {str(path)!r} do not fit the pocket network "
                                 f"({str(exc).splitlines()[0]}).") from None
        self.net.eval()

    def node_probability(self, padded: PaddedTer, grid: GridMap, frontiers: list[Frontier],
                         memo: dict[bytes, np.float32] | None = None) -> np.ndarray:
        """(N_max,) float32: each frontier node's probability that its pocket is small (a
        node sits at its frontier's goal cell; every frontier node is predicted in one
        batch); 0 for the other nodes.

        Args:
            padded: A decision's padded TER.
            grid: The partial map.
            frontiers: The frontiers the TER was built from.
            memo: The episode's predictions so far (see :meth:`small_probability`).
        """
        out = np.zeros(len(padded.node_mask), np.float32)
        nodes, which = node_frontiers(padded, grid, frontiers)
        if len(nodes):
            out[nodes] = self.small_probability(grid, [frontiers[i] for i in which], memo)
        return out

    def small_probability(self, grid: GridMap, frontiers: list[Frontier],
                          memo: dict[bytes, np.float32] | None = None) -> np.ndarray:
        """(n,) probability that each frontier's pocket is below ``small_area_m2``.

        Args:
            grid: The partial map.
            frontiers: The frontiers to predict.
            memo: Predictions already made, by what decides them (the frontier's window
                of :func:`frontier_windows`, its cells and length, digested), which this
                call reads and extends: a frontier whose window, cells and length did not
                change since an earlier decision of the episode (about 6 in 10 of a
                decision's frontiers) is neither cut into a patch nor predicted again.
                Keep one per episode (it grows by a few dozen bytes per new frontier). A
                remembered value is the one predicted then, in that decision's batch: it
                can differ from this batch's in the last bits of a float32 (convolutions
                sum in an order that depends on the batch size). None: predict every
                frontier.
        """
        if not frontiers:
            return np.zeros(0, np.float32)
        lengths = frontier_lengths(grid, frontiers)
        if memo is None:
            return self._predict(frontier_patches(grid, frontiers), lengths)
        windows = frontier_windows(grid, frontiers)
        keys = [_window_digest(window, cells, length)
                for (window, cells), length in zip(windows, lengths)]
        new = [i for i, key in enumerate(keys) if key not in memo]
        if new:
            patches = np.stack([window_patch(*windows[i]) for i in new])
            memo.update(zip((keys[i] for i in new), self._predict(patches, lengths[new])))
        return np.array([memo[key] for key in keys], np.float32)

    def _predict(self, patches: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """(n,) probabilities of patches (n, 3, S, S) uint8 and lengths (n,) metres."""
        with torch.no_grad():
            return torch.sigmoid(self.net(torch.from_numpy(patches),
                                          torch.from_numpy(lengths))).numpy()


def _window_digest(window: np.ndarray, cells: np.ndarray, length: np.float32) -> bytes:
    """What decides a frontier's prediction (its window, cells and length), digested."""
    digest = hashlib.blake2b(window.data, digest_size=16, key=length.tobytes())
    digest.update(np.ascontiguousarray(cells, np.int64).tobytes())
    return digest.digest()


_PREDICTORS: dict[tuple[str, float], PocketPredictor] = {}


def pocket_predictor(path: str | os.PathLike, sha256: str | None = None) -> PocketPredictor:
    """The predictor in ``path``, loaded once per process (again if the file changed).

    A relative ``path`` that is not there from the working directory is looked up from the
    repository root (``training/pockets.safetensors`` from anywhere).

    Raises:
        UserInputError: the file's sha256 does not begin with ``sha256`` (when given), or
            it cannot be loaded (see :class:`PocketPredictor`).
    """
    resolved = Path(path)
    if not resolved.is_absolute() and not resolved.exists():
        resolved = REPO / resolved
    resolved = resolved.resolve()
    try:
        key = (str(resolved), resolved.stat().st_mtime)
    except OSError:
        key = (str(resolved), 0.0)
    if key not in _PREDICTORS:
        _PREDICTORS[key] = PocketPredictor(resolved)
    if sha256 is not None and file_sha256(resolved) != sha256:
        raise UserInputError(
            f"the pocket predictor {str(resolved)!r} has sha256 {file_sha256(resolved)}, "
            f"not the {sha256} the policy was trained with: restore that file, or name the "
            "one it was trained with in observation.pockets.")
    return _PREDICTORS[key]
