"""A long episode in a large generated office: does memory stay bounded?

Generates a W x H m office (default 100 x 100), explores it with the nearest-frontier
explorer in full physics (no MCAP: its map snapshots alone would grow with the episode),
and samples the process's resident memory every 60 s of simulated time, with malloc's
thresholds fixed as the CLI does (mjexplore/episode/workers.py; --default-malloc for glibc's
defaults). Prints one JSON
line: the episode's end, its simulated time, peak RSS, and RSS at each quarter of the
episode (bounded memory: the later quarters grow only by the per-step logs, a few MB).

Usage: python tools/bench_long_episode.py [--size 100x100] [--max-time 20000]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * resource.getpagesize() / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="100x100")
    parser.add_argument("--max-time", type=float, default=20000.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--default-malloc", action="store_true",
                        help="leave glibc's malloc thresholds alone (the unbounded baseline)")
    args = parser.parse_args()
    from mjexplore.episode.workers import bound_heap_growth

    bounded = False if args.default_malloc else bound_heap_growth()
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.generate import generate_scene
    from mjexplore.scenes.scene import load_scene_files, write_scene

    w, h = (float(v) for v in args.size.split("x"))
    folder = Path(tempfile.mkdtemp()) / "scene"
    t0 = time.perf_counter()
    write_scene(generate_scene("office", w, h, args.seed), folder)
    scene = load_scene_files(folder)
    episode = Episode(scene, make_explorer("nearest"), args.seed,
                      EpisodeConfig(max_time=args.max_time))
    samples = [(0.0, rss_mb())]
    next_sample = 60.0
    while episode.step():
        if episode.sim.time >= next_sample:
            samples.append((episode.sim.time, rss_mb()))
            next_sample += 60.0
    result = episode.result()
    samples.append((episode.sim.time, rss_mb()))
    end = samples[-1][0]
    quarters = [min(samples, key=lambda s: abs(s[0] - q * end))[1] for q in (0.25, 0.5, 0.75, 1.0)]
    print(json.dumps({
        "scene": f"office {args.size} m", "malloc_thresholds_fixed": bounded,
        "grid_cells": int(scene.ground_truth.data.size),
        "end_reason": result.metrics["end_reason"],
        "exploration_ratio": result.metrics["exploration_ratio"],
        "sim_time_s": result.metrics["exploration_time_s"],
        "path_length_m": result.metrics["path_length_m"],
        "decisions": result.metrics["decisions"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "rss_mb_at_quarters": [round(q, 1) for q in quarters],
        "wall_s": round(time.perf_counter() - t0, 1)}))


if __name__ == "__main__":
    main()
