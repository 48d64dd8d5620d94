"""A learned GVN against the nearest-node rule on a training config's held-out layouts.

Runs :class:`~mjexplore.training.NearestNodeRule` and, with ``--weights``, the policy
(deterministic) through the config's model-selection episodes (``eval``: the generated
layouts training never draws, in the config's evaluation world), the same layouts and
seeds for both, and prints one JSON line: each one's mean exploration time (simulated s)
and explored count, per layout, and the policy's mean over the rule's (below 1: faster).

Usage: python tools/heldout_eval.py [--config training/gvn_v2.yaml] [--weights FILE]
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def summary(results: list[dict]) -> dict:
    return {"mean_exploration_time_s": round(float(np.mean(
                [r["exploration_time_s"] for r in results])), 2),
            "explored": sum(r["end_reason"] == "explored" for r in results),
            "per_layout_s": [r["exploration_time_s"] for r in results]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="training/gvn_v2.yaml")
    parser.add_argument("--weights", help="policy weights (.safetensors) to compare")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    from mjexplore.policies.weights import load_policy, weights_sha256
    from mjexplore.training import NearestNodeRule, evaluate_policy_episodes, load_train_config

    config = load_train_config(args.config)
    out = {"config": args.config, "layouts": len(config.eval.scene_list()),
           "nearest_node": summary(evaluate_policy_episodes(NearestNodeRule(), config))}
    if args.weights:
        policy, _ = load_policy(args.weights, expected_kind="gvn")
        out["policy"] = {"weights_sha256": weights_sha256(args.weights)[:16],
                         **summary(evaluate_policy_episodes(policy, config))}
        out["policy_over_rule"] = round(out["policy"]["mean_exploration_time_s"] /
                                        out["nearest_node"]["mean_exploration_time_s"], 4)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
