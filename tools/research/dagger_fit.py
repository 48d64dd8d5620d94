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

``--model linear`` fits, instead of the network, a conditional logit on the prior: each valid
node's logit is the prior's plus ``w . phi(node)``, with ``phi`` the node's information gain,
heading difference, distance and flag features, its pocket probability, its cost beyond the
cheapest valid node's (per 10 m, and whether under 5 m or 15 m), its straight-line distance
and gain near the robot (:func:`v3_prior.node_terms`); ``w`` by maximum likelihood (L-BFGS).
Does any per-node signature tell the teacher's departures apart?

Usage: python -m tools.research.dagger_fit runs/dagger/long [--holdout 0.25] [--loss margin]
    [--epochs 2] [--learning-rate 0.001] [--margin 1.0] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from tools.research.v3_prior import node_terms


def episode_ids(memory_mask: np.ndarray) -> np.ndarray:
    """(n,) episode index of each decision of a round, from its (n, E) memory mask: an
    episode starts at a decision with no remembered TER."""
    return np.cumsum(memory_mask.sum(1) == 0) - 1


def _linear_fit(node_features, masks, labels, fitted, seed):
    """The conditional logit's weights fitted on the rows ``fitted`` (see the docstring), and
    a function of rows to their most probable valid node."""
    import torch

    n, a = masks.shape
    if node_features.shape[1] != a * 10:
        raise SystemExit("--model linear reads v3 node features (10 a node): this run's "
                         "recipe has another observation")
    terms, prior = node_terms(node_features.reshape(n, a, -1), masks)
    valid = torch.as_tensor(masks)
    target = torch.as_tensor(labels)
    torch.manual_seed(seed)
    w = torch.zeros(terms.shape[-1], requires_grad=True)
    rows = torch.as_tensor(fitted)
    optimizer = torch.optim.LBFGS([w], max_iter=200)

    def closure():
        optimizer.zero_grad()
        logits = torch.where(valid[rows], prior[rows] + terms[rows] @ w, -1e9)
        loss = torch.nn.functional.cross_entropy(logits, target[rows]) + 1e-3 * w.square().sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        choice = torch.where(valid, prior + terms @ w, -1e9).argmax(1).numpy()
        first = torch.where(valid, prior, -torch.inf).argmax(1).numpy()
    return w.detach().numpy(), choice, first


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
    parser.add_argument("--model", choices=("network", "linear"), default="network",
                        help="fit the run's network, or a conditional logit on the prior "
                             "(default: network)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the held-out episodes and the minibatches' order "
                             "(default: 0)")
    args = parser.parse_args()

    import torch

    from mjexplore.config import from_dict
    from mjexplore.learning.dagger_run import read_round
    from mjexplore.learning.imitation import (
        agreement,
        clone,
        departure_figures,
        departures,
    )
    from mjexplore.learning.train_config import TrainConfig
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

    if args.model == "linear":
        w, choice, prior = _linear_fit(observations["node_features"], masks, labels, ~test,
                                       args.seed)
        out = {name: {"decisions": int(rows.sum()),
                      "agreement": float((choice == labels)[rows].mean()),
                      "prior_agreement": float((prior == labels)[rows].mean()),
                      **departure_figures(choice[rows], prior[rows], labels[rows])}
               for name, rows in splits.items()}
        print(json.dumps({"run": str(args.run), "rounds": len(record["rounds"]),
                          "episodes": count, "held_out_episodes": len(held), "model": "linear",
                          "weights": [round(float(x), 3) for x in w], "fitted": out}))
        return
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
