"""Benchmark of mapping and topology on a recorded exploration of the office; one JSON line.

A run of the office scene (the reactive wanderer, seeded, in full physics) is recorded
first: its scans and their poses. The replay then times, on one core:
    mapping_ms_*          integrating one 360-beam scan into the 0.05 m grid;
    ter_update_ms_*       one decision (every ``--decision-period`` simulated seconds; the
                          paper decides at 5 Hz): the incremental GVD updates for the scans
                          since the last decision plus building the TER (graph extraction,
                          frontiers, gains, links);
    gvd_update_ms_*       the incremental GVD part of it alone;
    full_recompute_ms_*   the bound: a full GVD from scratch at the same decisions with
                          scipy's distance_transform_edt and skimage's skeletonize (no graph,
                          no frontiers), sampled every ``--full-every`` decisions.
Medians and 99th percentiles in milliseconds. ``speedup_ter`` is full recomputation over
the whole decision (GVD + TER), ``speedup_gvd`` over the incremental GVD update alone (the
like-for-like comparison: both produce the GVD, only the first also builds a TER).

Usage: python tools/bench_topology.py [--seconds 600] [--decision-period 1.0]
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
from replay_timing import median_p99_ms, record_wander  # noqa: E402
from scipy import ndimage  # noqa: E402
from skimage.morphology import skeletonize  # noqa: E402

from mjexplore.mapping.metrics import exploration_ratio, observable_ground_truth  # noqa: E402
from mjexplore.mapping.occupancy import OccupancyMapper  # noqa: E402
from mjexplore.topology.pipeline import TopologyTracker  # noqa: E402

cv2.setNumThreads(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--decision-period", type=float, default=0.2)
    parser.add_argument("--full-every", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sim, scans = record_wander(args.scene, args.seconds, args.seed)
    gt = sim.scene.ground_truth

    # Warm-up on a copy, so that numba compilation is not timed.
    warm_mapper = OccupancyMapper.like(gt)
    warm = TopologyTracker(warm_mapper.state.shape)
    for scan in scans[:20]:
        warm.observe(warm_mapper.grid, warm_mapper.integrate(scan))
    warm.ter(warm_mapper.grid, np.array([*scans[19].pose[:2], 0.0]))

    mapper = OccupancyMapper.like(gt)
    tracker = TopologyTracker(mapper.state.shape)
    per_scan = max(1, int(round(args.decision_period * 10)))
    mapping, decisions, gvd_updates, full, nodes = [], [], [], [], []
    pending = 0.0
    for i, scan in enumerate(scans):
        t0 = time.perf_counter()
        changed = mapper.integrate(scan)
        t1 = time.perf_counter()
        tracker.observe(mapper.grid, changed)
        t2 = time.perf_counter()
        mapping.append(t1 - t0)
        pending += t2 - t1
        if i % per_scan == per_scan - 1:
            t3 = time.perf_counter()
            ter, _, _ = tracker.ter(mapper.grid, scan.pose)
            decisions.append(pending + time.perf_counter() - t3)
            gvd_updates.append(pending)
            nodes.append(len(ter.positions))
            pending = 0.0
            if len(decisions) % args.full_every == 0:
                t4 = time.perf_counter()
                free = mapper.grid.free
                ndimage.distance_transform_edt(free)
                skeletonize(free)
                full.append(time.perf_counter() - t4)
    er = exploration_ratio(mapper.grid, observable_ground_truth(gt))
    m_med, m_p99 = median_p99_ms(mapping)
    d_med, d_p99 = median_p99_ms(decisions)
    g_med, g_p99 = median_p99_ms(gvd_updates)
    f_med, f_p99 = median_p99_ms(full)
    print(json.dumps({
        "scene": args.scene,
        "grid_cells": int(gt.data.size),
        "resolution_m": gt.resolution,
        "scans": len(scans),
        "decisions": len(decisions),
        "exploration_ratio_at_end": round(er, 3),
        "ter_nodes_median": int(np.median(nodes)),
        "ter_nodes_max": int(np.max(nodes)),
        "mapping_ms_median": m_med,
        "mapping_ms_p99": m_p99,
        "ter_update_ms_median": d_med,
        "ter_update_ms_p99": d_p99,
        "gvd_update_ms_median": g_med,
        "gvd_update_ms_p99": g_p99,
        "full_recompute_ms_median": f_med,
        "full_recompute_ms_p99": f_p99,
        "speedup_ter": round(f_med / d_med, 1),
        "speedup_gvd": round(f_med / g_med, 1),
        "decision_period_s": args.decision_period,
    }))


if __name__ == "__main__":
    main()
