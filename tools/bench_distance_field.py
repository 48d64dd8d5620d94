"""The per-decision distance field of the v2 observation: bucket queue against the heap.

Runs the v2 training env (training/gvn_v2.yaml: grid world, generated layouts up to
40 x 25 m) with the nearest-node rule choosing, and at each decision times the path-cost
field from the robot to every cell (``Costmap.distances_from``) two ways on the same
costmap: the bucket queue it uses (Dial's algorithm) and the binary-heap Dijkstra (the
same search with an empty target mask). Prints one JSON line: the mean and median
milliseconds of each, the ratio of the means, and the largest relative difference between
the two fields.

Usage: python tools/bench_distance_field.py [--episodes 4] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    from mjexplore.envs import ExplorationEnv
    from mjexplore.learning.evaluation import NearestNodeRule
    from mjexplore.learning.train_config import load_train_config

    env = ExplorationEnv(load_train_config("training/gvn_v2.yaml").env)
    rule = NearestNodeRule()
    times: dict[str, list[float]] = {"buckets": [], "heap": []}
    worst = 0.0
    for episode in range(args.episodes):
        obs, _ = env.reset(seed=args.seed + episode)
        done = False
        while not done:
            state = env.episode.decision_state()
            costmap, xy = state.costmap, state.pose[:2]
            fields = {}
            for name, targets in (("buckets", None), ("heap", np.zeros(costmap.grid.shape, bool))):
                t = time.perf_counter()
                fields[name] = costmap.distances_from(xy, targets)
                times[name].append(time.perf_counter() - t)
            reached = np.isfinite(fields["heap"])
            if reached.any():
                worst = max(worst, float(np.max(np.abs(fields["buckets"][reached]
                                                       - fields["heap"][reached])
                                                / np.maximum(fields["heap"][reached], 1e-9))))
            action, _ = rule.predict(obs, action_masks=env.action_masks())
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    skip = 2  # numba compilation on the first calls.
    out: dict[str, float] = {"decisions": len(times["heap"])}
    for name, values in times.items():
        out[f"{name}_mean_ms"] = round(float(np.mean(values[skip:])) * 1e3, 2)
        out[f"{name}_median_ms"] = round(float(np.median(values[skip:])) * 1e3, 2)
    out["speedup"] = round(out["heap_mean_ms"] / out["buckets_mean_ms"], 2)
    out["max_relative_difference"] = worst
    print(json.dumps(out))


if __name__ == "__main__":
    main()
