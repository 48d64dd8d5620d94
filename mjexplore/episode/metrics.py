"""An episode's metrics: the paper's (ET, PL, IoU, exploration ratio) and more, all in
simulated time."""

from __future__ import annotations

from typing import Any

import numpy as np

from mjexplore.maps import GridMap
from mjexplore.sim.kinematics import KinematicsLog


def first_time_at(curve: np.ndarray, level: float) -> float | None:
    """First time (s) at which the ratio curve reaches ``level``, or None."""
    hit = np.flatnonzero(curve[:, 1] >= level)
    return round(float(curve[hit[0], 0]), 3) if len(hit) else None


# Exploration ratios whose first times are metrics (the paper's Fig. 5), and their keys.
MILESTONES = ((0.80, "t80_s"), (0.985, "t985_s"))


def episode_metrics(curve: np.ndarray, log: KinematicsLog, final_iou: float,
                    collisions: int, end_reason: str) -> dict[str, Any]:
    """The paper's metrics from an episode's records (all times simulated).

    Keys: ``iou``; ``exploration_ratio`` (final); ``exploration_time_s`` (ET: time at the
    end of the episode); ``path_length_m`` (PL: length of the true path of ``base_link``);
    ``odometry_path_length_m``; ``t80_s`` and ``t985_s`` (first times the ratio reaches
    0.80 and 0.985, None if never); ``collisions``; ``end_reason``; ``mean_speed_mps``.
    """
    odom = log.odom_pose[:, :2]
    t_end = float(curve[-1, 0])
    path = log.path_length()
    return {
        "iou": round(final_iou, 5),
        "exploration_ratio": round(float(curve[-1, 1]), 5),
        "exploration_time_s": round(t_end, 3),
        "path_length_m": round(path, 3),
        "odometry_path_length_m": round(float(np.linalg.norm(np.diff(odom, axis=0), axis=1).sum()), 3),
        **{key: first_time_at(curve, level) for level, key in MILESTONES},
        "collisions": int(collisions),
        "end_reason": end_reason,
        "mean_speed_mps": round(path / t_end, 4) if t_end > 0 else 0.0,
    }


class KnownCounter:
    """Exploration ratio kept up to date from the cells the mapper reports as changed."""

    def __init__(self, reference: GridMap) -> None:
        self.ref_known = reference.known.reshape(-1)
        self.total = int(self.ref_known.sum())
        self.known = np.zeros(self.ref_known.shape, bool)
        self.count = 0

    def update(self, state: np.ndarray, changed: np.ndarray, cols: int) -> float:
        if len(changed):
            flat = changed[:, 0] * cols + changed[:, 1]
            new = state.reshape(-1)[flat] >= 0
            ref = self.ref_known[flat]
            self.count += int((new & ref).sum() - (self.known[flat] & ref).sum())
            self.known[flat] = new
        return self.count / self.total
