"""Stress sweep: does any explorer stop before the map is explored? One JSON line.

Draws ``--layouts`` generated layouts (every family and pair of families, several sizes,
seeds from ``--seed``), explores each with every explorer in the grid world (the fastest
faithful one: the same lidar beams, mapping, topology, navigation and explorers as in
physics, without contact dynamics; it moves as the kinematic world does, ``--world
kinematic``), and prints: runs, how many reached the target ratio,
and the runs that ended before it, by explorer and end reason (``time_limit`` counts too:
an explorer that never finishes is as wrong as one that stops). ``failures`` lists the
first of those runs with their layout, so that one can be replayed with ``mjexplore
explore``. With ``--out FILE`` every finished run is appended to FILE (JSON lines, with the
git revision) as it ends, and a sweep started again with the same FILE skips the runs
already there: a sweep of hours survives being stopped, and the summary covers them all.

The time cap grows with the layout: ``--max-time`` simulated seconds, or
``--seconds-per-m2`` times the layout's area where that is longer (a 40 x 26 m layout has
three times the corridors of a 20 x 17 m one; a cap fixed for the small ones would count
a slow explorer on the large ones as one that stops).

Usage: python tools/stress_explorers.py [--layouts 200] [--explorers nearest,...]
       [--sizes small,medium,large] [--workers 2] [--seed 0] [--out runs/stress.jsonl]
       [--world grid] [--max-time 1800] [--seconds-per-m2 4]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import collections  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from mjexplore.io import provenance  # noqa: E402

EXPLORERS = "nearest,explore_lite,frontier_tsp,rrt,potential,oracle,gvn,cnn"
# Width and height ranges (metres) of each size class.
SIZES = {"small": ((10.0, 16.0), (8.0, 12.0)), "medium": ((16.0, 26.0), (12.0, 18.0)),
         "large": ((26.0, 40.0), (18.0, 26.0))}
BASE_FAMILIES = ("office", "maze", "loop", "corridor", "rooms", "hall", "labmaze")


def layouts(count: int, sizes: list[str], seed: int) -> list[tuple[str, float, float, int]]:
    """(family, width, height, seed) of ``count`` layouts: single families and pairs in
    turn, sizes drawn uniformly within each class in turn."""
    families = list(BASE_FAMILIES) + [f"{a}+{b}" for a, b in
                                      itertools.combinations(BASE_FAMILIES, 2)]
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        (w0, w1), (h0, h1) = SIZES[sizes[i % len(sizes)]]
        family = families[i % len(families)]
        out.append((family, round(float(rng.uniform(w0, w1)), 1),
                    round(float(rng.uniform(h0, h1)), 1), int(rng.integers(0, 2**31 - 1))))
    return out


def layout_label(layout: tuple[str, float, float, int]) -> str:
    """How runs name a layout: 'family WxH seed S' (what ``mjexplore scene-gen`` takes)."""
    family, width, height, seed = layout
    return f"{family} {width:g}x{height:g} seed {seed}"


def time_cap(layout: tuple[str, float, float, int], max_time: float,
             seconds_per_m2: float) -> float:
    """The layout's time cap in simulated seconds: ``max_time``, or ``seconds_per_m2``
    times its area where that is longer."""
    return max(max_time, round(seconds_per_m2 * layout[1] * layout[2], -1))


def explore(job: tuple[tuple[str, float, float, int], str, float, str]) -> dict:
    """One episode of ``explorer`` on the layout in ``world``; its end and ratio."""
    (family, width, height, seed), explorer, max_time, world = job
    import torch

    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.errors import UserInputError
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.generate import generate_scene
    from mjexplore.scenes.scene import load_scene_files, write_scene
    from mjexplore.sim.simulator import SimConfig

    torch.set_num_threads(1)
    record = {"layout": layout_label((family, width, height, seed)), "explorer": explorer}
    try:
        scene = generate_scene(family, width, height, seed)
    except UserInputError as exc:  # A size too small for a family: no layout, no run.
        return {**record, "end_reason": "no_layout", "error": str(exc)}
    config = EpisodeConfig(max_time=max_time, sim=SimConfig(dynamics=world))
    with tempfile.TemporaryDirectory() as tmp:
        files = load_scene_files(write_scene(scene, Path(tmp) / "scene"))
        m = Episode(files, make_explorer(explorer), seed % 1000, config).run().metrics
    return {**record, "end_reason": m["end_reason"], "exploration_ratio": m["exploration_ratio"],
            "exploration_time_s": m["exploration_time_s"], "fallbacks": m.get("fallbacks", 0),
            "max_time": max_time, "world": world}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--layouts", type=int, default=200)
    parser.add_argument("--explorers", default=EXPLORERS)
    parser.add_argument("--sizes", default="small,medium,large")
    parser.add_argument("--max-time", type=float, default=1800.0,
                        help="least time cap, simulated seconds")
    parser.add_argument("--seconds-per-m2", type=float, default=4.0,
                        help="time cap per square metre of layout, where longer")
    parser.add_argument("--world", choices=("grid", "kinematic"), default="grid")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON lines of finished runs: appended to, and skipped on a rerun")
    args = parser.parse_args()
    sizes = args.sizes.split(",")
    if args.layouts < 1 or any(s not in SIZES for s in sizes):
        parser.error(f"--layouts must be >= 1 and --sizes a list of {', '.join(SIZES)}")
    jobs = [(layout, explorer, time_cap(layout, args.max_time, args.seconds_per_m2),
             args.world)
            for layout in layouts(args.layouts, sizes, args.seed)
            for explorer in args.explorers.split(",")]
    results, done = [], set()
    if args.out is not None and args.out.exists():
        for line in args.out.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                results.append(r)
                done.add((r["layout"], r["explorer"], r.get("max_time", args.max_time),
                          r.get("world", "kinematic")))
    todo = [j for j in jobs
            if (layout_label(j[0]), j[1], j[2], j[3]) not in done]
    revision = provenance.git_revision()
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for r in pool.imap_unordered(explore, todo, chunksize=1):
            results.append(r)
            if args.out is not None:
                args.out.parent.mkdir(parents=True, exist_ok=True)
                with args.out.open("a") as f:  # One whole line per run: a kill loses none.
                    f.write(json.dumps({**r, "revision": revision}) + "\n")
    wanted = {(layout_label(j[0]), j[1]) for j in jobs}
    results = [r for r in results if (r["layout"], r["explorer"]) in wanted]
    ran = [r for r in results if r["end_reason"] != "no_layout"]
    premature: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for r in ran:
        if r["end_reason"] != "explored":
            premature[r["explorer"]][r["end_reason"]] += 1
    print(json.dumps({
        "runs": len(ran), "layouts": args.layouts,
        "revisions": sorted({r.get("revision", revision) for r in results}),
        "skipped_layouts": len({r["layout"] for r in results if r["end_reason"] == "no_layout"}),
        "reached_target": sum(r["end_reason"] == "explored" for r in ran),
        "premature": {e: dict(c) for e, c in sorted(premature.items())},
        "fallbacks": {e: sum(r["fallbacks"] for r in ran if r["explorer"] == e)
                      for e in args.explorers.split(",")},
        "failures": [r for r in ran if r["end_reason"] != "explored"][:20],
    }))


if __name__ == "__main__":
    main()
