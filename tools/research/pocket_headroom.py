"""How much knowing each frontier's pocket is worth: nearest-frontier variants on unseen
generated layouts, in the training world; prints one JSON line.

Modes (comma-separated ``--modes``), each driving the same episodes (layout, start, seed and
settings of a training config's evaluation, as ``mjexplore probe-policy --unseen`` does):

* ``nearest``: nearest-frontier;
* ``truth:A``: nearest-frontier passing over frontiers whose *true* pocket (the ground
  truth's unseen free space connected to them, ``pocket_areas``) is below A m^2, unless no
  other is left: what a perfect pocket predictor would be worth (privileged);
* ``predicted:M``: nearest-frontier counting each frontier M metres farther per unit of the
  predictor's probability that its pocket is small (the v3 GVN's prior, on frontiers);
* any explorer's name (``oracle``, ``potential``, ...).

Usage: python -m tools.research.pocket_headroom [--config training/gvn_v3.yaml]
    [--unseen 16] [--modes nearest,truth:0.5,predicted:50,oracle] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp

import numpy as np

from mjexplore.episode.explorer import ExplorationState


class PocketAwareNearest:
    """Nearest-frontier with a per-frontier extra cost (see the module docstring)."""

    name = "pocket_aware_nearest"

    def __init__(self, mode: str, predictor_path: str | None) -> None:
        kind, value = mode.split(":")
        self.kind, self.value = kind, float(value)
        self.predictor = None
        if kind == "predicted":
            from mjexplore.topology.pockets import pocket_predictor

            self.predictor = pocket_predictor(predictor_path)

    def reset(self, rng: np.random.Generator) -> None:
        del rng

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        from mjexplore.learning.pocket_training import nearest_goal
        from mjexplore.topology.pockets import pocket_areas

        if not state.frontiers:
            return None
        distance = state.frontier_distances()
        if self.kind == "truth":
            area = pocket_areas(state.grid, state.ground_truth, state.frontiers)
            return nearest_goal(state, distance, area, self.value)
        return nearest_goal(state, distance + self.value * self.predictor.small_probability(
            state.grid, state.frontiers))


def _episode(job: tuple[str, str, str]) -> dict:
    import torch

    from mjexplore.episode import Episode
    from mjexplore.explorers import make_explorer
    from mjexplore.learning.evaluation import heldout_env
    from mjexplore.learning.train_config import load_train_config

    config_path, mode, scene = job
    torch.set_num_threads(1)
    config = load_train_config(config_path)
    env = heldout_env(config, scene)
    env.reset(seed=config.eval.seed)
    ep = env.episode
    if ":" in mode:
        explorer = PocketAwareNearest(mode, config.env.observation.pockets)
    else:
        explorer = make_explorer(mode)
    metrics = Episode(ep.scene, explorer, ep.sim.config.seed, ep.config).run().metrics
    return {"mode": mode, "scene": scene, "time": metrics["exploration_time_s"],
            "explored": metrics["end_reason"] == "explored"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="training/gvn_v3.yaml")
    parser.add_argument("--unseen", type=int, default=16)
    parser.add_argument("--modes", default="nearest,truth:0.5,predicted:50,oracle")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    from mjexplore.learning.train_config import load_train_config

    modes = [m for m in args.modes.split(",") if m]
    scenes = load_train_config(args.config).eval.unseen_scenes(args.unseen)
    jobs = [(args.config, m, s) for s in scenes for m in modes]
    with mp.get_context("spawn").Pool(args.workers) as pool:
        rows = pool.map(_episode, jobs, chunksize=1)
    figures: dict = {"config": args.config, "layouts": len(scenes)}
    for mode in modes:
        mine = [r for r in rows if r["mode"] == mode]
        figures[f"{mode}_exploration_time_s"] = round(float(np.mean([r["time"] for r in mine])),
                                                      1)
        figures[f"{mode}_explored"] = sum(r["explored"] for r in mine)
    base = figures.get("nearest_exploration_time_s")
    if base:
        for mode in modes:
            figures[f"{mode}_over_nearest"] = round(figures[f"{mode}_exploration_time_s"] / base,
                                                    3)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
