"""Benchmark of scan-to-map matching on a recorded exploration of the office; one JSON line.

A run of the office (the reactive wanderer, seeded, kinematic world, the 360-beam ideal
lidar with 0.01 m noise) is recorded first: its scans and their true poses. The replay
then maps the scans at their true poses and, before integrating each, matches it against
the map so far from a prior off the truth by a seeded random offset (up to
``--offset`` metres and ``--offset-deg`` degrees per axis). It times, on one core:
    match_ms_*      one ``match_scan`` (the correlative search, its covariance and the
                    refinement);
    integrate_ms_*  one ``OccupancyMapper.integrate`` of the same scan, the same run's
                    baseline;
and reports medians and 99th percentiles in milliseconds, ``match_over_integrate`` (the
ratio of the medians), the share of matches accepted and the accepted matches' errors.

Usage: python tools/bench_scan_matching.py [--seconds 120] [--seed 0]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from replay_timing import median_p99_ms, record_wander  # noqa: E402

from mjexplore.mapping.occupancy import OccupancyMapper  # noqa: E402
from mjexplore.mapping.scan_matching import match_scan, scan_points  # noqa: E402
from mjexplore.sim.lidar import LidarConfig  # noqa: E402
from mjexplore.sim.odometry import wrap_angle  # noqa: E402
from mjexplore.sim.simulator import SimConfig  # noqa: E402

cv2.setNumThreads(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--offset", type=float, default=0.15)
    parser.add_argument("--offset-deg", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sim, scans = record_wander(args.scene, args.seconds, args.seed, SimConfig(
        dynamics="kinematic", lidar=LidarConfig(noise_std=0.01), seed=args.seed))
    gt = sim.scene.ground_truth
    rng = np.random.default_rng(args.seed)
    bound = np.array([args.offset, args.offset, math.radians(args.offset_deg)])

    # Warm-up on a copy, so that numba compilation is not timed.
    warm = OccupancyMapper.like(gt)
    for scan in scans[:5]:
        warm.integrate(scan)
        match_scan(scan_points(scan), warm.grid, scan.pose)

    mapper = OccupancyMapper.like(gt)
    mapper.integrate(scans[0])
    matching, integrating, trans, yaw = [], [], [], []
    accepted = 0
    for scan in scans[1:]:
        points = scan_points(scan)
        prior = scan.pose + rng.uniform(-1.0, 1.0, 3) * bound
        t0 = time.perf_counter()
        result = match_scan(points, mapper.grid, prior)
        t1 = time.perf_counter()
        mapper.integrate(scan)
        t2 = time.perf_counter()
        matching.append(t1 - t0)
        integrating.append(t2 - t1)
        if result.accepted:
            accepted += 1
            trans.append(float(np.hypot(*(result.pose[:2] - scan.pose[:2]))))
            yaw.append(abs(math.degrees(wrap_angle(result.pose[2] - scan.pose[2]))))
    m_med, m_p99 = median_p99_ms(matching)
    i_med, i_p99 = median_p99_ms(integrating)
    print(json.dumps({
        "scene": args.scene,
        "beams": int(len(scans[0].ranges)),
        "matches": len(matching),
        "match_ms_median": m_med,
        "match_ms_p99": m_p99,
        "integrate_ms_median": i_med,
        "integrate_ms_p99": i_p99,
        "match_over_integrate": round(m_med / i_med, 1),
        "accepted_share": round(accepted / len(matching), 3),
        "error_m_median": round(float(np.median(trans)), 4),
        "error_m_p99": round(float(np.percentile(trans, 99)), 4),
        "error_deg_median": round(float(np.median(yaw)), 3),
        "error_deg_p99": round(float(np.percentile(yaw, 99)), 3),
        "prior_offset_m": args.offset,
        "prior_offset_deg": args.offset_deg,
    }))


if __name__ == "__main__":
    main()
