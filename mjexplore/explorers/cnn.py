"""The "Naive Exp" baseline (paper ref. [27]): a CNN policy picks a global goal cell on the
map image; the reachable frontier nearest that cell is driven to."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from mjexplore.explorers.base import ExplorationState, register, shipped_policy

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[2] / "training" / "cnn_policy.safetensors"


@register("cnn")
class CnnExplorer:
    """Chooses goals with a trained CNN policy.

    Args:
        policy: Weights file (default: the shipped ``training/cnn_policy.safetensors``).
        deterministic: Take the most probable cell (True) or sample.
    """

    def __init__(self, policy: str | os.PathLike | None = None,
                 deterministic: bool = True) -> None:
        from mjexplore.policies.weights import load_policy, weights_sha256

        self.policy, meta = load_policy(policy or DEFAULT_WEIGHTS, expected_kind="cnn")
        self.weights_sha256 = weights_sha256(policy or DEFAULT_WEIGHTS)
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


@register("cnn_v2")
class CnnV2Explorer(CnnExplorer):
    """The CNN baseline trained with the v2 recipe (training/cnn_v2.yaml), its weights
    ``training/cnn_v2_policy.safetensors``."""

    def __init__(self, policy: str | os.PathLike | None = None,
                 deterministic: bool = True) -> None:
        super().__init__(policy or shipped_policy(
            DEFAULT_WEIGHTS.with_name("cnn_v2_policy.safetensors"), "cnn_v2"), deterministic)
