"""The "Naive Exp" baseline (paper ref. [27]): a CNN policy picks a global goal cell on the
map image; the reachable frontier nearest that cell is driven to."""

from __future__ import annotations

import os

import numpy as np
import torch

from mjexplore.episode.explorer import ExplorationState
from mjexplore.policies.models import resolve_policy, run_label
from mjexplore.policies.weights import load_policy, policy_recipe, weights_sha256


class CnnExplorer:
    """Chooses goals with a trained CNN policy (always masked: only cells with a reachable
    frontier near them are goals).

    Args:
        policy: A shipped model's name, a weights file, or a folder holding
            ``policy.safetensors``; None: the recommended model (``cnn_paper``).
        deterministic: Take the most probable cell (True) or sample.
    """

    name = "cnn"

    def __init__(self, policy: str | os.PathLike | None = None,
                 deterministic: bool = True) -> None:
        self.policy_name, path = resolve_policy(policy, "cnn")
        self.policy, meta = load_policy(path, expected_kind="cnn")
        self.weights_sha256 = weights_sha256(path)
        self.policy_recipe = policy_recipe(path, meta)  # For run records (metrics.json).
        self.label = run_label("cnn", self.policy_name, True, "iam")
        self.decisions = meta["decisions"]
        self.deterministic = deterministic
        self.reset(np.random.default_rng(0))

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.decisions.reset()

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        d = self.decisions
        if not d.prepare(state):
            return None
        obs = {k: torch.as_tensor(v)[None] for k, v in d.observation().items()}
        with torch.no_grad():
            dist = self.policy.get_distribution(obs, action_masks=d.mask[None])
            if self.deterministic:
                action = int(dist.distribution.probs.argmax())
            else:
                p = dist.distribution.probs[0].double().numpy()
                action = int(self.rng.choice(len(p), p=p / p.sum()))
        goal, _ = d.act(action)
        return goal
