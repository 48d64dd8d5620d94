"""Benchmarks that replay a recorded exploration of the office; one JSON line each.

Each benchmark records a run of the office scene (the reactive wanderer, seeded) first and
then times its replay on one core; medians and 99th percentiles in milliseconds. With no
subcommand the three run in turn, each printing its own line.

``topology``: mapping and topology. The run is in full physics: its scans and their poses.
The replay times:
    mapping_ms_*          integrating one 360-beam scan into the 0.05 m grid;
    ter_update_ms_*       one decision (every ``--decision-period`` simulated seconds; the
                          paper decides at 5 Hz): the incremental GVD updates for the scans
                          since the last decision plus building the TER (graph extraction,
                          frontiers, gains, links);
    gvd_update_ms_*       the incremental GVD part of it alone;
    full_recompute_ms_*   the bound: a full GVD from scratch at the same decisions with
                          scipy's distance_transform_edt and skimage's skeletonize (no graph,
                          no frontiers), sampled every ``--full-every`` decisions.
``speedup_ter`` is full recomputation over the whole decision (GVD + TER), ``speedup_gvd``
over the incremental GVD update alone (the like-for-like comparison: both produce the GVD,
only the first also builds a TER).

``scan_matching``: scan-to-map matching. The run is in the kinematic world with the 360-beam
ideal lidar with 0.01 m noise: its scans and their true poses. The replay maps the scans at
their true poses and, before integrating each, matches it against the map so far from a
prior off the truth by a seeded random offset (up to ``--offset`` metres and
``--offset-deg`` degrees per axis). It times:
    match_ms_*      one ``match_scan`` (the correlative search, its covariance and the
                    refinement);
    integrate_ms_*  one ``OccupancyMapper.integrate`` of the same scan, the same run's
                    baseline;
and reports ``match_over_integrate`` (the ratio of the medians), the share of matches
accepted and the accepted matches' errors.

``localizer``: the episodes' localiser (:class:`FusedLocalizer`). The run is in the
kinematic world with the LDS-01 lidar and ``typical`` odometry error: its scans and the
odometry at each. The replay feeds the same scans and odometry to two localisers and a
mapper, timing:
    correct_ms_*        one ``FusedLocalizer.correct`` with the default settings (its
                        density of returns on 2 cm cells);
    correct_ms_5cm_*    the same on 5 cm cells (the map's; the setting before sub-cell
                        deposits), the same run's baseline;
    integrate_ms_*      one ``OccupancyMapper.integrate`` of the scan at the estimate;
and reports the ratio of the correct medians and each localiser's final and RMS position
error against the truth.

Usage: python tools/bench_replay.py            # all three in turn, with their defaults
       python tools/bench_replay.py topology [--seconds 600] [--decision-period 1.0]
       python tools/bench_replay.py scan_matching [--seconds 120] [--seed 0]
       python tools/bench_replay.py localizer [--seconds 120] [--seed 0]
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
from scipy import ndimage  # noqa: E402
from skimage.morphology import skeletonize  # noqa: E402

from mjexplore.episode.metrics import pose_errors  # noqa: E402
from mjexplore.mapping.localization import FusedLocalizer, LocalizerConfig  # noqa: E402
from mjexplore.mapping.metrics import exploration_ratio, observable_ground_truth  # noqa: E402
from mjexplore.mapping.occupancy import OccupancyMapper  # noqa: E402
from mjexplore.mapping.scan_matching import deskew_scan, match_scan, scan_points  # noqa: E402
from mjexplore.navigation.wander import WanderController  # noqa: E402
from mjexplore.scenes.canonical import resolve_scene  # noqa: E402
from mjexplore.sim.lidar import LidarConfig, lidar_model  # noqa: E402
from mjexplore.sim.odometry import wrap_angle  # noqa: E402
from mjexplore.sim.simulator import SimConfig, Simulator  # noqa: E402
from mjexplore.topology.pipeline import TopologyTracker  # noqa: E402

cv2.setNumThreads(1)


# --- Shared by the benchmarks ---------------------------------------------------------------

def record_wander(scene: str, seconds: float, seed: int, config: SimConfig | None = None):
    """The simulator after ``seconds`` (simulated) of the seeded wanderer in ``scene``, and
    every scan of the run."""
    sim = Simulator(resolve_scene(scene), config)
    controller = WanderController(rng=np.random.default_rng(seed))
    scans = [sim.latest_scan]
    while sim.time < seconds - 1e-9:
        sim.command(*controller(sim.latest_scan, sim.pose))
        scans += sim.step(0.1)
    return sim, scans


def median_p99_ms(values_s: list[float]) -> tuple[float, float]:
    """Median and 99th percentile of timings given in seconds, in milliseconds."""
    ms = np.asarray(values_s) * 1e3
    return round(float(np.median(ms)), 3), round(float(np.percentile(ms, 99)), 3)


# --- topology ---------------------------------------------------------------------------------

def topology_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--decision-period", type=float, default=0.2)
    parser.add_argument("--full-every", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)


def run_topology(args: argparse.Namespace) -> None:
    """Benchmark of mapping and topology on a recorded exploration of the office; one JSON line."""
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
    }), flush=True)


# --- scan_matching ----------------------------------------------------------------------------

def scan_matching_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--offset", type=float, default=0.15)
    parser.add_argument("--offset-deg", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=0)


def run_scan_matching(args: argparse.Namespace) -> None:
    """Benchmark of scan-to-map matching on a recorded exploration of the office; one JSON line."""
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
    }), flush=True)


# --- localizer --------------------------------------------------------------------------------

def record_localization(scene: str, seconds: float, seed: int):
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


def replay_localizer(sim, run, config: LocalizerConfig):
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


def localizer_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=0)


def run_localizer(args: argparse.Namespace) -> None:
    """Benchmark of the episodes' localiser (FusedLocalizer) on the office; one JSON line."""
    sim, run = record_localization(args.scene, args.seconds, args.seed)
    lidar = sim.lidar.config
    fine = LocalizerConfig.for_lidar(lidar)
    coarse = LocalizerConfig.for_lidar(lidar, density_resolution=0.05)
    replay_localizer(sim, run[:10], fine)  # Warm-up: numba compilation is not timed.
    fine_ms, integrate_ms, *fine_track = replay_localizer(sim, run, fine)
    coarse_ms, _, *coarse_track = replay_localizer(sim, run, coarse)
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
    }), flush=True)


# --- Command line -----------------------------------------------------------------------------

BENCHMARKS = {
    "topology": (topology_options, run_topology),
    "scan_matching": (scan_matching_options, run_scan_matching),
    "localizer": (localizer_options, run_localizer),
}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="With no benchmark named, all three run in turn with their defaults.")
    sub = parser.add_subparsers(dest="benchmark", metavar="{" + ",".join(BENCHMARKS) + "}")
    subparsers = {}
    for name, (options, bench) in BENCHMARKS.items():
        summary = bench.__doc__.splitlines()[0]
        subparsers[name] = sub.add_parser(name, help=summary, description=summary)
        options(subparsers[name])
    args = parser.parse_args(argv)
    if args.benchmark is not None:
        BENCHMARKS[args.benchmark][1](args)
        return
    for name, (_, bench) in BENCHMARKS.items():
        bench(subparsers[name].parse_args([]))


if __name__ == "__main__":
    main()
