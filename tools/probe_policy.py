"""How much a trained policy has learned: it against chance and a greedy rule, same layouts.

Runs whole episodes of the training env of a config (its decision space, reward, procedural
layouts and training-mode dynamics) on held-out seeds with three ways to choose each action:

* ``policy``: the trained policy, its most probable valid action (as the explorers use it);
* ``random``: a valid action drawn uniformly (what an untrained policy amounts to);
* ``greedy``: the valid action nearest the robot: with v2 or v3 observations the node
  nearest along the known map (:class:`~mjexplore.learning.evaluation.NearestNodeRule`, what
  nearest-frontier ranks by), otherwise the one placed nearest in a straight line (for the
  grid decisions, roughly the nearest frontier);
* ``prior``: a residual policy's prior alone, its logits without the network's (v3: the
  nearest node counting each ``policy.prior_pocket_m`` metres farther per unit of its
  pocket probability; v2: as ``greedy``): what the network's residual adds is ``policy``
  against it.

With ``--heldout`` or ``--unseen``, a classic explorer's name (``nearest``, ``oracle``, ...) is
a mode too: that explorer drives the same episode (layout, start pose, seed and settings)
on its own, a reference such as the ground-truth bound; it has no return.

Every mode sees the same layouts and start poses: episode seed ``--seed-base + i`` (training
draws its layouts from the config's seed, so these are unseen layouts of the same
distribution), or with ``--heldout`` the config's model-selection layouts (``eval``: the
generated layouts training never draws, its episode settings and seed; one episode each),
or with ``--unseen N`` the N generated layouts after those (the same generator seeds'
sequence, seen by neither training nor model selection; evaluation settings as
``--heldout``). Without ``--config`` the config is the one stored with the weights.
Prints one JSON line: per mode the mean return, simulated exploration time (s), path length
(m) and how many episodes were explored, and ``learned_fraction``, where the policy's mean
return lies between random (0) and greedy (1).

Usage: python tools/probe_policy.py --weights models/cnn_paper/policy.safetensors
    [--config training/cnn.yaml] [--episodes 10 | --heldout | --unseen 32]
    [--modes policy,random,greedy[,prior,nearest,oracle]] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp

from mjexplore.eval.probe import MODES, probe_config, probe_episode

DEFAULT_MODES = ("policy", "random", "greedy")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", help="training YAML (its env is used; default: the "
                                         "config stored with the weights)")
    parser.add_argument("--weights", required=True, help="exported policy (.safetensors)")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed-base", type=int, default=10_000)
    parser.add_argument("--heldout", action="store_true",
                        help="the config's model-selection layouts instead of --episodes")
    parser.add_argument("--unseen", type=int, default=0,
                        help="this many generated layouts past the model-selection ones")
    parser.add_argument("--modes", default=",".join(DEFAULT_MODES),
                        help=f"comma-separated, of {', '.join(MODES)}")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    modes = [m for m in args.modes.split(",") if m]
    if not modes:
        parser.error(f"--modes takes {', '.join(MODES)} (and, with --heldout or --unseen, "
                     "explorer names)")
    explorers = sorted(set(modes) - set(MODES))
    if "prior" in modes:
        from mjexplore.envs.observation import POSED

        config = probe_config(args.config, args.weights)
        if config.kind != "gvn" or config.env.observation.features not in POSED:
            parser.error("--modes prior needs a GVN with v2 or v3 observations")
    if explorers and not (args.heldout or args.unseen):
        parser.error("explorer modes need --heldout or --unseen (a given layout)")
    for name in explorers:
        from mjexplore.errors import UserInputError
        from mjexplore.explorers import make_explorer

        try:
            make_explorer(name)
        except UserInputError as exc:
            parser.error(f"--modes: {exc}")

    if args.heldout or args.unseen:
        evaluation = probe_config(args.config, args.weights).eval
        scenes = (evaluation.unseen_scenes(args.unseen) if args.unseen
                  else evaluation.scene_list())
        episodes = [(evaluation.seed, scene) for scene in scenes]
    else:
        episodes = [(args.seed_base + i, None) for i in range(args.episodes)]
    jobs = [(args.config, args.weights, mode, seed, scene)
            for seed, scene in episodes for mode in modes]
    with mp.get_context("spawn").Pool(args.workers) as pool:
        rows = pool.map(probe_episode, jobs, chunksize=1)
    layouts = (f"{args.unseen} past model selection" if args.unseen else
               "heldout" if args.heldout else f"seeds from {args.seed_base}")
    figures: dict = {"config": args.config or "stored with the weights",
                     "weights": args.weights, "episodes": len(episodes), "layouts": layouts}
    for mode in modes:
        mine = [r for r in rows if r["mode"] == mode]
        for key in ("return", "exploration_time_s", "path_length_m"):
            if mine[0][key] is not None:
                figures[f"{mode}_{key}"] = round(sum(r[key] for r in mine) / len(mine), 3)
        figures[f"{mode}_explored"] = sum(r["explored"] for r in mine)
    if set(DEFAULT_MODES) <= set(modes):
        span = figures["greedy_return"] - figures["random_return"]
        figures["learned_fraction"] = (round((figures["policy_return"]
                                              - figures["random_return"]) / span, 3)
                                       if span else None)
    if {"policy", "greedy"} <= set(modes):
        figures["policy_over_greedy_time"] = round(figures["policy_exploration_time_s"]
                                                   / figures["greedy_exploration_time_s"], 3)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
