"""How well does a fit of DAgger's labelled decisions carry to episodes it did not see?

Reads the finished rounds of a DAgger run folder (``mjexplore imitate``), holds out a share
of its episodes (drawn with ``--seed``; an episode starts where the observation's memory is
empty), fits the run's untrained network to the rest with the run's imitation settings (or
those given: ``--loss``, ``--epochs``, ``--learning-rate``, ``--margin``) and prints one JSON
line: the fit's figures, and on the fitted and the held-out decisions the agreement with
the labels and :func:`~mjexplore.learning.imitation.departures` (how the labels and the
learner leave the prior: a student beats its prior only with departures that mostly take
the label), beside the same figures of the untrained network (its prior).

No env runs: a variant of the fit is judged in minutes, before a DAgger run uses it.

Usage: python tools/dagger_fit.py runs/dagger/long [--holdout 0.25] [--loss margin]
    [--epochs 2] [--learning-rate 0.001] [--margin 1.0] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def episode_ids(memory_mask: np.ndarray) -> np.ndarray:
    """(n,) episode index of each decision of a round, from its (n, E) memory mask: an
    episode starts at a decision with no remembered TER."""
    return np.cumsum(memory_mask.sum(1) == 0) - 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="DAgger run folder (mjexplore imitate)")
    parser.add_argument("--holdout", type=float, default=0.25,
                        help="share of episodes held out (default: 0.25)")
    parser.add_argument("--loss", choices=("cross_entropy", "margin"), default=None,
                        help="the fit's loss (default: the run's)")
    parser.add_argument("--epochs", type=int, default=None,
                        help="passes over the fitted decisions (default: the run's)")
    parser.add_argument("--learning-rate", type=float, default=None,
                        help="Adam's step size (default: the run's)")
    parser.add_argument("--margin", type=float, default=None,
                        help="the margin loss's margin, nats (default: the run's)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the held-out episodes and the minibatches' order "
                             "(default: 0)")
    args = parser.parse_args()

    import torch

    from mjexplore.config import from_dict
    from mjexplore.learning.dagger_run import read_round
    from mjexplore.learning.imitation import agreement, clone, departures
    from mjexplore.learning.training import TrainConfig
    from mjexplore.policies.weights import load_policy

    torch.set_num_threads(1)
    record = json.loads((args.run / "imitation.json").read_text())
    config = from_dict(TrainConfig, record["config"], "the run's config")
    overrides = {k: v for k, v in (("loss", args.loss), ("epochs", args.epochs),
                                   ("learning_rate", args.learning_rate),
                                   ("margin", args.margin)) if v is not None}
    imitation = dataclasses.replace(config.imitation, dagger_iterations=0, **overrides)
    parts, episodes = [], []
    for i in range(len(record["rounds"])):
        observations, masks, labels, _ = read_round(args.run / "rounds" / f"round_{i:03d}.npz")
        parts.append((observations, masks, labels))
        ids = episode_ids(observations["memory_mask"])
        episodes.append(ids + (episodes[-1].max() + 1 if episodes else 0))
    observations = {k: np.concatenate([p[0][k] for p in parts]) for k in parts[0][0]}
    masks = np.concatenate([p[1] for p in parts])
    labels = np.concatenate([p[2] for p in parts])
    episode = np.concatenate(episodes)
    rng = np.random.default_rng(args.seed)
    count = int(episode.max()) + 1
    held = rng.permutation(count)[:max(1, round(args.holdout * count))]
    test = np.isin(episode, held)
    splits = {"fitted": ~test, "held_out": test}

    def figures(policy) -> dict:
        out = {}
        for name, rows in splits.items():
            obs = {k: v[rows] for k, v in observations.items()}
            out[name] = {"decisions": int(rows.sum()),
                         "agreement": agreement(policy, obs, masks[rows], labels[rows]),
                         **departures(policy, obs, masks[rows], labels[rows])}
        return out

    policy, _ = load_policy(args.run / "policy_untrained.safetensors")
    before = figures(policy)
    tick = time.perf_counter()
    fitted = {k: v[~test] for k, v in observations.items()}
    fit = clone(policy, fitted, masks[~test], labels[~test], imitation, seed=args.seed)
    print(json.dumps({"run": str(args.run), "rounds": len(record["rounds"]),
                      "episodes": count, "held_out_episodes": len(held),
                      "fit": {"loss": imitation.loss, "epochs": imitation.epochs,
                              "learning_rate": imitation.learning_rate,
                              "margin": imitation.margin, "final_loss": fit["loss"],
                              "fit_agreement": fit["agreement"],
                              "wall_s": round(time.perf_counter() - tick, 1)},
                      "untrained": before, "fitted": figures(policy)}))


if __name__ == "__main__":
    main()
