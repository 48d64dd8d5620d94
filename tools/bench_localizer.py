"""Benchmark of the episodes' localiser (:class:`FusedLocalizer`) on the office; one JSON line.

A run of the office (the reactive wanderer, seeded, kinematic world, the LDS-01 lidar and
``typical`` odometry error) is recorded first: its scans and the odometry at each. The
replay feeds the same scans and odometry to two localisers and a mapper, timing on one
core:
    correct_ms_*        one ``FusedLocalizer.correct`` with the default settings (its
                        density of returns on 2 cm cells);
    correct_ms_5cm_*    the same on 5 cm cells (the map's; the setting before sub-cell
                        deposits), the same run's baseline;
    integrate_ms_*      one ``OccupancyMapper.integrate`` of the scan at the estimate;
and reports medians and 99th percentiles in milliseconds, the ratio of the correct medians
and each localiser's final and RMS position error against the truth.

Usage: python tools/bench_localizer.py [--seconds 120] [--seed 0]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from replay_timing import median_p99_ms  # noqa: E402

from mjexplore.episode.metrics import pose_errors  # noqa: E402
from mjexplore.mapping.localization import FusedLocalizer, LocalizerConfig  # noqa: E402
from mjexplore.mapping.occupancy import OccupancyMapper  # noqa: E402
from mjexplore.mapping.scan_matching import deskew_scan  # noqa: E402
from mjexplore.navigation.wander import WanderController  # noqa: E402
from mjexplore.scenes.canonical import resolve_scene  # noqa: E402
from mjexplore.sim.lidar import lidar_model  # noqa: E402
from mjexplore.sim.simulator import SimConfig, Simulator  # noqa: E402

cv2.setNumThreads(1)


def record(scene: str, seconds: float, seed: int):
    """Scans (de-skewed along the odometry), the odometry and the true pose at each."""
    sim = Simulator(resolve_scene(scene), SimConfig(
        dynamics="kinematic", lidar=lidar_model("lds01"), odometry_error="typical",
        seed=seed))
    controller = WanderController(rng=np.random.default_rng(seed))
    out = [(sim.latest_scan, sim.odom_pose, sim.pose)]
    while sim.time < seconds - 1e-9:
        sim.command(*controller(sim.latest_scan, sim.pose))
        for scan in sim.step(0.1):
            rows = sim.kinematics_rows
            k = int(np.argmin(np.abs(rows[:, 0] - scan.stamp)))
            out.append((deskew_scan(scan, trajectory=(rows[:, 0], rows[:, 8:11])),
                        rows[k, 8:11], rows[k, 5:8]))
    return sim, out


def replay(sim, run, config: LocalizerConfig):
    loc = FusedLocalizer(run[0][2], odom_pose=run[0][1], config=config)
    mapper = OccupancyMapper.like(sim.scene.ground_truth)
    correcting, integrating, positions = [], [], []
    for scan, odom, truth in run:
        loc.advance(odom)
        t0 = time.perf_counter()
        loc.correct(scan, mapper)
        t1 = time.perf_counter()
        mapper.integrate(scan, loc.sensor_pose)
        t2 = time.perf_counter()
        correcting.append(t1 - t0)
        integrating.append(t2 - t1)
        positions.append((*loc.pose[:2], *truth[:2]))
    positions = np.array(positions)
    return correcting, integrating, positions[:, :2], positions[:, 2:]


def track_errors(estimated: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """RMS and final position error of an estimated track (n, 2) against the truth, m."""
    final = round(float(np.hypot(*(estimated[-1] - truth[-1]))), 4)
    return pose_errors(estimated, truth)["pose_error_rmse_m"], final


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sim, run = record(args.scene, args.seconds, args.seed)
    lidar = sim.lidar.config
    fine = LocalizerConfig.for_lidar(lidar)
    coarse = LocalizerConfig.for_lidar(lidar, density_resolution=0.05)
    replay(sim, run[:10], fine)  # Warm-up: numba compilation is not timed.
    fine_ms, integrate_ms, *fine_track = replay(sim, run, fine)
    coarse_ms, _, *coarse_track = replay(sim, run, coarse)
    fine_rmse, fine_final = track_errors(*fine_track)
    coarse_rmse, coarse_final = track_errors(*coarse_track)
    f_med, f_p99 = median_p99_ms(fine_ms)
    c_med, c_p99 = median_p99_ms(coarse_ms)
    i_med, i_p99 = median_p99_ms(integrate_ms)
    print(json.dumps({
        "scene": args.scene,
        "scans": len(run),
        "correct_ms_median": f_med,
        "correct_ms_p99": f_p99,
        "correct_ms_5cm_median": c_med,
        "correct_ms_5cm_p99": c_p99,
        "integrate_ms_median": i_med,
        "integrate_ms_p99": i_p99,
        "correct_over_5cm": round(f_med / c_med, 3),
        "pose_error_rmse_m": fine_rmse,
        "pose_error_rmse_m_5cm": coarse_rmse,
        "pose_error_final_m": fine_final,
        "pose_error_final_m_5cm": coarse_final,
    }))


if __name__ == "__main__":
    main()
