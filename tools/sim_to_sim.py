"""Sim-to-sim check: the same explorers and seeds in the grid world and in full physics.

For each evaluation scene, explorer and seed, one episode in each world (the CLI's episode
settings: ideal lidar with 0.01 m noise, 1800 s cap); the grid world scans as training
runs it (``--grid-scans travel``: training/gvn_v2.yaml's ``scan_travel``) or at the lidar's
rate (``rate``). Prints one JSON line (per scene and explorer: mean ET in each world and
their ratio, runs that reached the target) and, with ``--out``, writes the table as
markdown with the code revision (atomically).

Usage: python tools/sim_to_sim.py [--scenes loop_with_corridor,maze,office]
       [--explorers nearest,gvn] [--seeds 3] [--workers 2] [--grid-scans travel|rate]
       [--out docs/sim_to_sim.md]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

WORLDS = ("grid", "physics")
SCHEDULES = {"travel": "by travel, as training/gvn_v2.yaml's scan_travel has it",
             "rate": "at the lidar's rate"}


def training_scan_travel():
    """The grid world's scans by travel as the training config has them."""
    from mjexplore.io.provenance import REPO
    from mjexplore.learning.train_config import load_train_config

    return load_train_config(REPO / "training" / "gvn_v2.yaml").env.episode.sim.scan_travel


def run(job: tuple) -> dict:
    """One episode (scene, explorer, seed, world, the grid world's ScanTravel or None); its
    world, ET and end."""
    scene, explorer, seed, world, travel = job
    import torch

    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.lidar import lidar_model
    from mjexplore.sim.simulator import SimConfig

    torch.set_num_threads(1)
    config = EpisodeConfig(sim=SimConfig(dynamics=world,
                                         scan_travel=travel if world == "grid" else None,
                                         lidar=lidar_model("ideal", noise_std=0.01)))
    m = Episode(resolve_scene(scene), make_explorer(explorer), seed, config).run().metrics
    return {"scene": scene, "explorer": explorer, "seed": seed, "world": world,
            "et": m["exploration_time_s"], "explored": m["end_reason"] == "explored"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="loop_with_corridor,maze,office")
    parser.add_argument("--explorers", default="nearest,gvn")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--grid-scans", choices=("travel", "rate"), default="travel",
                        help="the grid world's scans: by travel as in training (default) "
                             "or at the lidar's rate")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    scenes, explorers = args.scenes.split(","), args.explorers.split(",")
    travel = training_scan_travel() if args.grid_scans == "travel" else None
    jobs = [(s, e, seed, w, travel) for s in scenes for e in explorers
            for seed in range(args.seeds) for w in WORLDS]
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        results = pool.map(run, jobs, chunksize=1)
    from mjexplore.io.atomic import write_text_atomic
    from mjexplore.io.provenance import git_revision

    rows, table = [], {}
    for s in scenes:
        for e in explorers:
            cell = {w: [r for r in results if (r["scene"], r["explorer"], r["world"]) ==
                        (s, e, w)] for w in WORLDS}
            et = {w: float(np.mean([r["et"] for r in cell[w]])) for w in WORLDS}
            done = {w: sum(r["explored"] for r in cell[w]) for w in WORLDS}
            ratio = et["grid"] / et["physics"]
            table[f"{s}/{e}"] = {"et_grid_s": round(et["grid"], 1),
                                 "et_physics_s": round(et["physics"], 1),
                                 "grid_over_physics": round(ratio, 3),
                                 "explored_grid": done["grid"],
                                 "explored_physics": done["physics"]}
            rows.append(f"| {s} | {e} | {et['grid']:.1f} | {et['physics']:.1f} | "
                        f"{ratio:.3f} | {done['grid']}/{args.seeds} | "
                        f"{done['physics']}/{args.seeds} |")
    revision = git_revision()
    print(json.dumps({"revision": revision, "seeds": args.seeds,
                      "grid_scans": args.grid_scans, **table}))
    if args.out is not None:
        write_text_atomic(args.out, "\n".join([
            "# Sim-to-sim: the grid world against full physics", "",
            f"Mean exploration time (s, simulated) to 98.5 % or the end over seeds "
            f"0-{args.seeds - 1}, the same explorer and seed in each world (the CLI's "
            f"episode settings; the grid world scanning {SCHEDULES[args.grid_scans]}), "
            f"from `python tools/sim_to_sim.py --seeds {args.seeds} --grid-scans "
            f"{args.grid_scans} --out {args.out}` at revision `{revision}`.", "",
            "| scene | explorer | ET grid | ET physics | grid / physics | explored grid | "
            "explored physics |", "|---|---|---|---|---|---|---|", *rows, ""]))


if __name__ == "__main__":
    main()
