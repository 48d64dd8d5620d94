"""Benchmark of the explorers' decisions on the office; one JSON line.

Each explorer explores the office (kinematic mode, seed 0) for ``--seconds`` simulated
seconds while every call of its ``select_goal`` is timed on one core. Printed per explorer:
``decision_ms_median``, ``decision_ms_p95`` and ``decision_ms_p99`` (milliseconds) and
``decision_vs_nearest`` (its median over nearest-frontier's, measured in the same run). For
an explorer that predicts the map (``predicted_tour``) also ``prediction_ms_median`` and
``_p95``: the prediction alone (coarse channels, the network, spreading it over the map).
For the oracle also
``oracle_initial_plan_s`` (candidate views, path graph and the first tour: what its first
decision costs) and ``oracle_resolve_ms_median`` / ``_p99`` (the later decisions: the
re-solve of cover and tour).

Bounds (issue 15): oracle_initial_plan_s <= 5, oracle re-solve <= 200 ms, frontier_tsp's
median <= 100 ms; (issue 49) prediction <= 30 ms, a prediction-using decision's p95 <= 250
ms.

Usage: python tools/bench_explorers.py [--seconds 300] [--explorers nearest,...]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from mjexplore.episode import Episode, EpisodeConfig  # noqa: E402
from mjexplore.explorers import make_explorer  # noqa: E402
from mjexplore.scenes.canonical import resolve_scene  # noqa: E402
from mjexplore.sim.simulator import SimConfig  # noqa: E402

EXPLORERS = "nearest,explore_lite,frontier_tsp,rrt,potential,oracle,gvn,cnn"


def _timed(call, times: list[float]):
    """``call`` that appends the wall-clock seconds of each call to ``times``."""

    def timed(*args):
        t0 = time.perf_counter()
        out = call(*args)
        times.append(time.perf_counter() - t0)
        return out

    return timed


def decision_times(scene, name: str, seconds: float) -> tuple[list[float], list[float]]:
    """Wall-clock seconds of each ``select_goal`` call while exploring, and of each map
    prediction within them (none for an explorer that predicts nothing)."""
    explorer = make_explorer(name)
    times: list[float] = []
    predictions: list[float] = []
    explorer.select_goal = _timed(explorer.select_goal, times)
    planner = getattr(explorer, "planner", None)
    if planner is not None and hasattr(planner, "free_probability"):
        planner.free_probability = _timed(planner.free_probability, predictions)
    config = EpisodeConfig(max_time=seconds, sim=SimConfig(dynamics="kinematic"))
    Episode(scene, explorer, 0, config).run()
    return times, predictions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seconds", type=float, default=300.0,
                        help="simulated seconds explored per explorer")
    parser.add_argument("--explorers", default=EXPLORERS)
    args = parser.parse_args()
    torch.set_num_threads(1)
    scene = resolve_scene(args.scene)
    out: dict[str, float | int | str] = {"scene": args.scene, "seconds": args.seconds}
    medians = {}
    for name in args.explorers.split(","):
        times, predictions = decision_times(scene, name, args.seconds)
        times = np.asarray(times) * 1e3
        if predictions:
            predictions = np.asarray(predictions) * 1e3
            out[f"{name}_prediction_ms_median"] = round(float(np.median(predictions)), 2)
            out[f"{name}_prediction_ms_p95"] = round(float(np.percentile(predictions, 95)), 2)
        if name == "oracle" and len(times):
            out["oracle_initial_plan_s"] = round(float(times[0]) / 1e3, 3)
            later = times[1:] if len(times) > 1 else times
            out["oracle_resolve_ms_median"] = round(float(np.median(later)), 2)
            out["oracle_resolve_ms_p99"] = round(float(np.percentile(later, 99)), 2)
            times = later
        medians[name] = float(np.median(times))
        out[f"{name}_decisions"] = int(len(times))
        out[f"{name}_decision_ms_median"] = round(medians[name], 2)
        out[f"{name}_decision_ms_p95"] = round(float(np.percentile(times, 95)), 2)
        out[f"{name}_decision_ms_p99"] = round(float(np.percentile(times, 99)), 2)
    if "nearest" in medians:
        for name, median in medians.items():
            out[f"{name}_decision_vs_nearest"] = round(median / medians["nearest"], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
