"""Benchmark of a sweep on Ray against the process pool; one JSON line.

The same sweep (physics, ``--scene``, nearest frontier, ``--max-time`` simulated seconds an
episode) runs with ``bench --workers W`` and with ``bench --ray`` (a local Ray instance of
W CPUs), each twice: with ``--small`` and with ``--large`` episodes (seeds), into fresh
folders. The wall time of each sweep, start-up included, is printed, and from the two sizes
per backend: ``episode_s`` (the marginal wall time per episode: (T_large - T_small) /
(large - small)), ``startup_s`` (T_small - small x episode_s: starting the workers or the
Ray instance, the first imports) and ``ray_overhead_per_episode_s`` (Ray's episode_s minus
the pool's: sending the scene, the task, the run folder's files back), with
``ray_vs_pool`` (Ray's total over the pool's at ``--large``), all measured in this run.

Usage: python tools/bench_ray_sweep.py [--workers 2] [--small 4] [--large 12]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def sweep_seconds(out: Path, seeds: int, args: argparse.Namespace, ray: bool) -> float:
    """Wall time of one ``mjexplore bench`` command, run as a user runs it."""
    cmd = [sys.executable, "-m", "mjexplore.cli", "bench", "--scenes", args.scene,
           "--explorers", "nearest", "--seeds", str(seeds), "--max-time", str(args.max_time),
           "--workers", str(args.workers), "--no-progress", "--out", str(out)]
    start = time.perf_counter()
    subprocess.run(cmd + (["--ray"] if ray else []), check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--small", type=int, default=4)
    parser.add_argument("--large", type=int, default=12)
    parser.add_argument("--scene", default="train_loop")
    parser.add_argument("--max-time", type=float, default=20.0)
    args = parser.parse_args()
    result = {"workers": args.workers, "scene": args.scene, "max_time_s": args.max_time,
              "episodes": [args.small, args.large]}
    with tempfile.TemporaryDirectory() as tmp:
        for name, ray in (("pool", False), ("ray", True)):
            small = sweep_seconds(Path(tmp) / f"{name}_small", args.small, args, ray)
            large = sweep_seconds(Path(tmp) / f"{name}_large", args.large, args, ray)
            episode = (large - small) / (args.large - args.small)
            result[name] = {"total_s": [round(small, 2), round(large, 2)],
                            "episode_s": round(episode, 3),
                            "startup_s": round(small - args.small * episode, 2)}
    result["ray_overhead_per_episode_s"] = round(
        result["ray"]["episode_s"] - result["pool"]["episode_s"], 3)
    result["ray_vs_pool"] = round(result["ray"]["total_s"][1] / result["pool"]["total_s"][1], 3)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
