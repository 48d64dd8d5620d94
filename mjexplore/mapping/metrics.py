"""Map-quality metrics against the ground truth, in the paper's terms.

All metrics compare an estimated trinary map with the *observable* ground truth: the
ground truth's free cells and those occupied cells that touch free space (8-neighbours),
i.e. the wall surfaces a lidar can see. The inside of thick walls and solid blocks can
never be observed by any robot and would cap the exploration ratio below 100 %, so it is
left out (treated as unknown) of the reference.

Definitions, with E the estimate, R the observable reference, and sets of cells:
    exploration ratio (ER) = |known(E) & known(R)| / |known(R)|
        where known = free or occupied (the paper's "area of the built map, free and
        occupied, over the ground-truth layout"; Explore-Bench's known cells over the
        ground truth's known cells).
    IoU = mean over c in {free, occupied} of |E_c & R_c| / |E_c | R_c|, with E_c and R_c
        the cells each labels c, counted over the cells known in R (ref. [43]: the
        intersection over union of the built map and the ground-truth layout).
    accuracy (paper Eq. 18) = number of cells whose label (free, occupied, unknown) in E
        equals the label in R.
"""

from __future__ import annotations

import cv2
import numpy as np

from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap


def observable_ground_truth(ground_truth: GridMap) -> GridMap:
    """The reference map: free cells, and occupied cells 8-adjacent to a free cell."""
    free = ground_truth.free
    touching = cv2.dilate(free.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    data = np.full(ground_truth.shape, UNKNOWN, np.int8)
    data[free] = FREE
    data[ground_truth.occupied & touching] = OCCUPIED
    return GridMap(data, ground_truth.resolution, ground_truth.origin)


def _check(estimate: GridMap, reference: GridMap) -> None:
    if estimate.shape != reference.shape:
        raise ValueError(f"estimate {estimate.shape} and reference {reference.shape} differ in "
                         "shape: build the mapper with OccupancyMapper.like(ground_truth).")


def exploration_ratio(estimate: GridMap, reference: GridMap) -> float:
    """Share of the reference's known cells that the estimate knows (free or occupied)."""
    _check(estimate, reference)
    ref_known = reference.known
    total = int(ref_known.sum())
    return float((estimate.known & ref_known).sum() / total) if total else 0.0


def iou(estimate: GridMap, reference: GridMap) -> float:
    """Mean of the free-space IoU and the occupied-space IoU (see the module docstring)."""
    return float(np.mean(class_iou(estimate, reference)))


def class_iou(estimate: GridMap, reference: GridMap) -> tuple[float, float]:
    """(free IoU, occupied IoU) over the cells known in the reference."""
    _check(estimate, reference)
    scope = reference.known
    out = []
    for est_c, ref_c in ((estimate.free, reference.free), (estimate.occupied, reference.occupied)):
        est_c = est_c & scope
        union = int((est_c | ref_c).sum())
        out.append(float((est_c & ref_c).sum() / union) if union else 1.0)
    return out[0], out[1]


def trinary(grid: GridMap) -> np.ndarray:
    """Labels -1 unknown, 0 free, 100 occupied (occupancy thresholded at 50 %)."""
    labels = np.full(grid.shape, UNKNOWN, np.int8)
    labels[grid.free] = FREE
    labels[grid.occupied] = OCCUPIED
    return labels


def accuracy(estimate: GridMap, reference: GridMap) -> int:
    """Number of cells with the same trinary label in both maps (paper Eq. 18)."""
    _check(estimate, reference)
    return int((trinary(estimate) == trinary(reference)).sum())
