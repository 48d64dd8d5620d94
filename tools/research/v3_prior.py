"""What the analyses of gvn_v3's path prior (pocket_nearest's rule) share: the recipe they
need, the per-node terms of a linear model on the prior, an episode's time with a penalty
for not exploring, and the paired comparison of times on the same layouts.

Used by ``dagger_fit``, ``es_residual`` and ``rollout_advantage`` (this folder).
"""

from __future__ import annotations

import argparse

import numpy as np


def node_terms(node_features, valid):
    """(n, N, 10) the linear model's terms of each node and the prior's logits (n, N) at
    1 m per nat, from v3 node features (n, N, 10) and the valid mask (n, N)."""
    import torch

    from mjexplore.envs.observation import POCKET
    from mjexplore.policies.gvn import path_prior

    f = torch.as_tensor(node_features)
    valid = torch.as_tensor(valid)
    prior = path_prior(f, 1.0, 50.0)  # The v3 recipes' prior: 50 m per unit of pocket.
    cost = -prior
    cheapest = torch.where(valid, cost, torch.inf).min(1, keepdim=True).values
    beyond = torch.clamp(cost - cheapest, max=200.0)
    near = (beyond < 15).float()
    terms = torch.stack([f[..., 2], f[..., 3], f[..., 4], f[..., 5], f[..., POCKET],
                         beyond / 10, torch.hypot(f[..., 0], f[..., 1]) / 10,
                         (beyond < 5).float(), near, f[..., 2] * near], -1)
    return terms, prior


def penalised_time(metrics: dict, config) -> float:
    """An episode's exploration time, seconds; one that does not explore counts the
    evaluation's time limit plus 1000 s per unit of coverage missing."""
    if metrics["end_reason"] == "explored":
        return float(metrics["exploration_time_s"])
    return float(config.eval.episode.max_time + 1000.0 * (1.0 - metrics["exploration_ratio"]))


def paired(times: np.ndarray, base: np.ndarray) -> dict:
    """Mean times and :func:`~mjexplore.eval.stats.compare_paired`'s figures of per-layout
    ratios (times / base)."""
    from mjexplore.eval.stats import compare_paired

    c = compare_paired(times, base)
    return {"mean": float(np.mean(times)), "base": float(np.mean(base)), "ratio": c.mean,
            "ci95": [c.low, c.high], "faster": c.faster, "slower": c.slower,
            "p_value": c.p_value}


def load_v3_recipe(parser: argparse.ArgumentParser, path: str):
    """The training recipe at ``path``; ``parser.error`` (exit 2) unless it has what the
    prior's rule needs: generated training layouts, v3 features and the v3 prior."""
    from mjexplore.config import load_yaml_config
    from mjexplore.learning.train_config import TrainConfig

    config = load_yaml_config(TrainConfig, path)
    if (config.env.procedural is None or config.env.observation.features != "v3"
            or config.policy.prior_pocket_m != 50.0):
        parser.error(f"{path}: needs generated training layouts (env.procedural), v3 "
                     "features and the v3 prior (policy.prior_pocket_m: 50), as "
                     "training/gvn_batch.yaml has")
    return config
