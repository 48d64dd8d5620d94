"""Predicting the unseen map: per cell of the partial occupancy map, the probability that it
is free, from the map alone.

What separates an explorer's rule from the ground-truth oracle is the layout it has not
seen yet; floor plans are regular enough (rooms behind doors, corridors that run on, walls
that continue) that much of it can be guessed from what is mapped. :class:`MapPredictorNet`,
a small U-Net, reads the map on a coarse grid of ``cell_m`` cells (0.2 m: a block of 4 x 4
cells of a 0.05 m map) and gives a logit per coarse cell that the cell is free
(:func:`coarse_channels`: the shares of each block known free and known occupied, and
whether it lies inside the map; :func:`coarse_truth`: the ground truth's free share, the
target where the partial map leaves the block unknown). It is trained by supervision on
partial maps recorded at the decisions of episodes on generated layouts
(:mod:`mjexplore.learning.predictor_training`). Its uncertainty is Monte Carlo dropout: the
spread of the probability over passes with the bottleneck's dropout on.

Three non-learned predictors stand beside it (:data:`BASELINES`): unknown as free, unknown
as occupied, and OpenCV's inpainting of the known free share (Telea's method) into the
unknown cells. :func:`prediction_quality` scores any of them on the unknown cells: binary
cross-entropy, accuracy, IoU of the free space and the expected calibration error.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.io.provenance import REPO
from mjexplore.io.tensor_file import read_tensor_file
from mjexplore.maps import GridMap, is_free, is_occupied

CELL_M = 0.2  # The predictor's cell side, metres.
CHANNELS = ("free", "occupied", "inside")
FORMAT = "mjexplore-map-predictor-v1"
DEPTH = 3  # Poolings of the U-Net: a coarse map's sides are padded to multiples of 2**DEPTH.


def block_shares(mask: np.ndarray, k: int) -> np.ndarray:
    """(ceil(rows / k), ceil(cols / k)) float32 share of each k x k block of ``mask`` that
    is set (cells past the map's edge count as unset)."""
    rows, cols = mask.shape
    out_r, out_c = -(-rows // k), -(-cols // k)
    padded = np.zeros((out_r * k, out_c * k), np.float32)
    padded[:rows, :cols] = mask
    return padded.reshape(out_r, k, out_c, k).mean(axis=(1, 3))


def block_size(grid: GridMap, cell_m: float = CELL_M) -> int:
    """Map cells per coarse cell along each axis.

    Raises:
        UserInputError: ``cell_m`` is not a whole multiple of the map's resolution.
    """
    k = int(round(cell_m / grid.resolution))
    if k < 1 or abs(k * grid.resolution - cell_m) > 1e-6:
        raise UserInputError(f"the map predictor's {cell_m} m cells need a map whose "
                             f"resolution divides them, not {grid.resolution} m.")
    return k


def coarse_channels(grid: GridMap, cell_m: float = CELL_M) -> np.ndarray:
    """(3, H, W) uint8 input of the predictor: the share of each ``cell_m`` block of
    ``grid`` known free and known occupied (0-255) and 255 inside the map."""
    k = block_size(grid, cell_m)
    free = block_shares(is_free(grid.data), k)
    occupied = block_shares(is_occupied(grid.data), k)
    inside = block_shares(np.ones(grid.shape, bool), k) > 0
    return np.stack([np.round(255 * free), np.round(255 * occupied),
                     255 * inside]).astype(np.uint8)


def coarse_truth(ground_truth: GridMap, cell_m: float = CELL_M) -> np.ndarray:
    """(H, W) uint8 share (0-255) of each ``cell_m`` block of the ground truth that is free:
    the target (free where at least half is)."""
    return np.round(255 * block_shares(ground_truth.free, block_size(ground_truth, cell_m))
                    ).astype(np.uint8)


def unknown_cells(channels: np.ndarray) -> np.ndarray:
    """(H, W) bool: the coarse cells inside the map that are mostly unknown (less than half
    known free or occupied): where a prediction is made and scored."""
    known = channels[0].astype(np.int32) + channels[1]
    return (channels[2] > 0) & (known < 128)


def _conv(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU())


class MapPredictorNet(nn.Module):
    """A U-Net: ``DEPTH`` poolings, channels ``width`` x 1, 2, 4, 8, dropout in the
    bottleneck; (B, 3, H, W) uint8 or [0, 255] float coarse channels in, (B, H, W) free
    logits out (H and W multiples of 2**DEPTH).

    Args:
        width: Channels of the first level.
        dropout: Channel dropout in the bottleneck (Monte Carlo dropout at prediction).
    """

    def __init__(self, width: int = 16, dropout: float = 0.1) -> None:
        super().__init__()
        widths = [width * 2 ** i for i in range(DEPTH + 1)]
        self.down = nn.ModuleList([_conv(len(CHANNELS), widths[0])] +
                                  [_conv(widths[i], widths[i + 1]) for i in range(DEPTH)])
        self.dropout = nn.Dropout2d(dropout)
        self.up = nn.ModuleList([nn.ConvTranspose2d(widths[i + 1], widths[i], 2, stride=2)
                                 for i in reversed(range(DEPTH))])
        self.merge = nn.ModuleList([_conv(2 * widths[i], widths[i])
                                    for i in reversed(range(DEPTH))])
        self.head = nn.Conv2d(widths[0], 1, 1)

    def forward(self, channels: torch.Tensor) -> torch.Tensor:
        x = channels.to(torch.float32) / 255.0
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else nn.functional.max_pool2d(x, 2))
            skips.append(x)
        x = self.dropout(skips.pop())
        for up, merge in zip(self.up, self.merge):
            x = merge(torch.cat([up(x), skips.pop()], 1))
        return self.head(x)[:, 0]


def pad_to_depth(channels: np.ndarray) -> np.ndarray:
    """(3, H', W') ``channels`` padded (outside the map: zeros) to sides that are multiples
    of 2**DEPTH."""
    m = 2 ** DEPTH
    _, rows, cols = channels.shape
    out = np.zeros((channels.shape[0], -(-rows // m) * m, -(-cols // m) * m), channels.dtype)
    out[:, :rows, :cols] = channels
    return out


def free_probability(net: MapPredictorNet, channels: np.ndarray) -> np.ndarray:
    """(H, W) float32 free probability of one pass of ``net`` (in its current mode) over
    (3, H, W) coarse channels."""
    rows, cols = channels.shape[1:]
    with torch.no_grad():
        x = torch.from_numpy(pad_to_depth(channels))[None]
        return torch.sigmoid(net(x))[0, :rows, :cols].numpy()


def save_map_predictor(path: str | os.PathLike, net: MapPredictorNet,
                       provenance: dict | None = None) -> None:
    """Writes the predictor's weights and its layout (safetensors, atomically)."""
    from safetensors.torch import save

    tensors = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    # The width is the first level's channels, which the head takes in.
    meta = {"format": FORMAT, "cell_m": repr(CELL_M), "channels": json.dumps(CHANNELS),
            "width": str(net.head.in_channels), "dropout": repr(net.dropout.p),
            "provenance": json.dumps(provenance or {}, default=str)}
    write_bytes_atomic(path, save(tensors, metadata=meta))


class MapPredictor:
    """A trained :class:`MapPredictorNet` from its weights file, for inference on one core.

    Args:
        path: A file written by :func:`save_map_predictor` (``mjexplore train-predictor``).

    Raises:
        UserInputError: unreadable, not a map predictor, or for another input layout.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        hint = "give the predictor.safetensors that 'mjexplore train-predictor' wrote."
        tensors, meta = read_tensor_file(self.path, "the map predictor", hint)
        try:
            ours = (meta.get("format") == FORMAT and float(meta["cell_m"]) == CELL_M
                    and json.loads(meta["channels"]) == list(CHANNELS))
            width, dropout = int(meta["width"]), float(meta["dropout"])
            self.provenance = json.loads(meta.get("provenance", "{}"))
        except (KeyError, TypeError, ValueError):
            ours = False
        if not ours:
            raise UserInputError(f"{str(path)!r} is not a map predictor of this version "
                                 f"(format {meta.get('format')!r}); {hint}")
        self.net = MapPredictorNet(width, dropout)
        try:
            self.net.load_state_dict(tensors)
        except RuntimeError as exc:
            raise UserInputError(f"weights in {str(path)!r} do not fit the map predictor "
                                 f"({str(exc).splitlines()[0]}).") from None
        self.net.eval()

    def predict_channels(self, channels: np.ndarray, samples: int = 1,
                         seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Free probability and its Monte Carlo dropout spread per coarse cell.

        Args:
            channels: (3, H, W) uint8 coarse channels (:func:`coarse_channels`).
            samples: Passes; 1: dropout off, no spread.
            seed: Seed of the dropout masks.

        Returns:
            (H, W) float32 mean probability and (H, W) float32 standard deviation over the
            passes (zeros with one pass).
        """
        if samples <= 1:
            p = free_probability(self.net, channels)
            return p, np.zeros_like(p)
        rows, cols = channels.shape[1:]
        x = torch.from_numpy(pad_to_depth(channels))[None]
        with torch.no_grad():
            self.net.dropout.train()
            try:
                with torch.random.fork_rng(devices=[]):
                    torch.manual_seed(seed)
                    probs = torch.sigmoid(self.net(x.expand(samples, -1, -1, -1)))
            finally:
                self.net.dropout.eval()
            p = probs[:, :rows, :cols].numpy()
            return p.mean(0), p.std(0)

    def __call__(self, channels: np.ndarray) -> np.ndarray:
        """(H, W) float32 free probability (one pass, dropout off)."""
        return self.predict_channels(channels)[0]


_PREDICTORS: dict[tuple[str, float], MapPredictor] = {}


def map_predictor(path: str | os.PathLike) -> MapPredictor:
    """The predictor in ``path``, loaded once per process (again if the file changed); a
    relative ``path`` that is not there from the working directory is looked up from the
    repository root.

    Raises:
        UserInputError: the file is missing or is not a map predictor.
    """
    resolved = Path(path)
    if not resolved.is_absolute() and not resolved.exists():
        resolved = REPO / resolved
    if not resolved.is_file():
        raise UserInputError(f"no map predictor at {str(path)!r}: train one with 'mjexplore "
                             "train-predictor' and give its predictor.safetensors.")
    resolved = resolved.resolve()
    key = (str(resolved), resolved.stat().st_mtime)
    if key not in _PREDICTORS:
        _PREDICTORS[key] = MapPredictor(resolved)
    return _PREDICTORS[key]


def unknown_as_free(channels: np.ndarray) -> np.ndarray:
    """Every unknown cell free (probability 1); known cells as mapped."""
    return np.where(unknown_cells(channels), 1.0, _known_free(channels)).astype(np.float32)


def unknown_as_occupied(channels: np.ndarray) -> np.ndarray:
    """Every unknown cell not free (probability 0); known cells as mapped."""
    return np.where(unknown_cells(channels), 0.0, _known_free(channels)).astype(np.float32)


def inpainted(channels: np.ndarray, radius_cells: int = 5) -> np.ndarray:
    """The known free share inpainted into the unknown cells (``cv2.inpaint``, Telea's
    method, ``radius_cells`` around each), as a probability."""
    unknown = unknown_cells(channels)
    known = np.where(unknown, 0.0, _known_free(channels))
    image = np.round(255 * known).astype(np.uint8)
    filled = cv2.inpaint(image, unknown.astype(np.uint8), radius_cells, cv2.INPAINT_TELEA)
    return np.where(unknown, filled / 255.0, known).astype(np.float32)


def _known_free(channels: np.ndarray) -> np.ndarray:
    """The known free share of each known cell's known part (free / (free + occupied))."""
    free = channels[0].astype(np.float32)
    known = free + channels[1]
    return np.divide(free, known, out=np.zeros_like(free), where=known > 0)


BASELINES = {"unknown_as_free": unknown_as_free, "unknown_as_occupied": unknown_as_occupied,
             "inpainting": inpainted}


def unknown_within(channels: np.ndarray, within_m: float) -> np.ndarray:
    """(H, W) bool: the unknown cells (:func:`unknown_cells`) whose centre lies within
    ``within_m`` metres of a known cell's centre inside the map."""
    unknown = unknown_cells(channels)
    known = (channels[2] > 0) & ~unknown
    if not known.any():
        return np.zeros_like(unknown)
    distance = cv2.distanceTransform((~known).astype(np.uint8), cv2.DIST_L2,
                                     cv2.DIST_MASK_PRECISE) * CELL_M
    return unknown & (distance <= within_m + 1e-6)


# (greatest free probability called a wall, least called free): the cells a planner on the
# prediction trusts; it leaves the others unknown.
CONFIDENT = (0.3, 0.7)


def prediction_quality(pairs, bins: int = 10, within_m: float | None = None,
                       confident: tuple[float, float] = CONFIDENT
                       ) -> dict[str, float | None]:
    """Scores free probabilities on the unknown cells of many maps together.

    Args:
        pairs: Iterable of (probability (H, W), channels (3, H, W), truth (H, W) uint8
            free share): each map's prediction, input and target.
        bins: Probability bins of the calibration error.
        within_m: Score only the unknown cells within this many metres of a known cell
            (:func:`unknown_within`); None: every unknown cell.
        confident: (greatest probability called a wall, least called free): the cells a
            planner on the prediction trusts (:data:`CONFIDENT`, the planners' defaults).

    Returns:
        ``cells`` scored; ``bce`` (nats, probabilities clipped to [1e-4, 1 - 1e-4]);
        ``accuracy`` at 0.5; ``iou_free`` of the predicted and true free cells;
        ``ece``: the cells' share-weighted gap between mean probability and free share per
        bin; ``free_share`` of the scored cells; ``confident_share``, the share of them
        at or beyond ``confident``, and ``confident_accuracy``, the accuracy on those
        (None when there are none).
    """
    probability, target = [], []
    for p, channels, truth in pairs:
        unknown = unknown_cells(channels) if within_m is None else \
            unknown_within(channels, within_m)
        probability.append(np.asarray(p, np.float64)[unknown])
        target.append(truth[unknown] >= 128)
    p = np.concatenate(probability) if probability else np.zeros(0)
    t = np.concatenate(target) if target else np.zeros(0, bool)
    if not len(p):
        raise ValueError("no unknown cells to score")
    clipped = np.clip(p, 1e-4, 1 - 1e-4)
    bce = -np.mean(np.where(t, np.log(clipped), np.log1p(-clipped)))
    called = p >= 0.5
    union = (called | t).sum()
    sure = (p <= confident[0]) | (p >= confident[1])
    which = np.minimum((p * bins).astype(int), bins - 1)
    count = np.bincount(which, minlength=bins)
    gap = np.abs(np.bincount(which, p, bins) - np.bincount(which, t.astype(float), bins))
    return {"cells": int(len(p)), "bce": round(float(bce), 4),
            "accuracy": round(float((called == t).mean()), 4),
            "iou_free": round(float((called & t).sum() / union), 4) if union else 1.0,
            "ece": round(float(gap.sum() / count.sum()), 4),
            "free_share": round(float(t.mean()), 4),
            "confident_share": round(float(sure.mean()), 4),
            "confident_accuracy": (round(float((called == t)[sure].mean()), 4)
                                   if sure.any() else None)}
