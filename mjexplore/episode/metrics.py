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
        "odometry_path_length_m": round(
            float(np.linalg.norm(np.diff(odom, axis=0), axis=1).sum()), 3),
        **{key: first_time_at(curve, level) for level, key in MILESTONES},
        "collisions": int(collisions),
        "end_reason": end_reason,
        "mean_speed_mps": round(path / t_end, 4) if t_end > 0 else 0.0,
    }


def pose_errors(estimated: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Position errors of an estimated trajectory, as is and after the rigid alignment that
    fits it best to the truth.

    The aligned error is the absolute trajectory error of SLAM benchmarks (Sturm et al.,
    "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012: least-squares
    rotation and translation, Umeyama's closed form in 2-D): what stays once the estimate's
    frame (a heading error at the start turns the whole map) is set aside, i.e. the
    distortion of the trajectory and of the map built along it.

    Args:
        estimated: (n, 2) estimated (x, y) of ``base_link`` in ``map``, metres.
        truth: (n, 2) the true positions at the same instants.

    Returns:
        ``pose_error_rmse_m``, ``pose_error_max_m`` and ``pose_error_aligned_rmse_m``
        (metres; all 0 without samples).
    """
    estimated = np.asarray(estimated, np.float64).reshape(-1, 2)
    truth = np.asarray(truth, np.float64).reshape(-1, 2)
    if len(truth) == 0:
        return {"pose_error_rmse_m": 0.0, "pose_error_max_m": 0.0,
                "pose_error_aligned_rmse_m": 0.0}
    raw = np.hypot(*(estimated - truth).T)
    est_c, truth_c = estimated - estimated.mean(0), truth - truth.mean(0)
    u, _, vt = np.linalg.svd(truth_c.T @ est_c)
    flip = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])  # A rotation, never a reflection.
    aligned = np.hypot(*(est_c @ (u @ flip @ vt).T - truth_c).T)
    return {"pose_error_rmse_m": round(float(np.sqrt(np.mean(raw ** 2))), 4),
            "pose_error_max_m": round(float(raw.max()), 4),
            "pose_error_aligned_rmse_m": round(float(np.sqrt(np.mean(aligned ** 2))), 4)}


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
