"""The GVN explorer: a trained policy picks a TER node at each decision (the paper's method).

When frontiers remain but none is a TER node (the TER links a frontier only where a GVD
vertex of the robot's component, or the robot, sees it), it answers None and the episode
takes the nearest frontier (counted in ``fallbacks`` of metrics.json), so that the episode
does not end with open frontiers.

The policy's episodic memory of a ``v1`` policy is kept here as encoded fragments: with
fixed weights, encoding each decision's TER once and caching its fragment gives the same
numbers as re-encoding the raw memory at every decision (as training does), at a tenth of
the cost. A ``v2`` policy's fragments depend on where the robot is now (the memory's poses
are relative to it), so it runs the policy on the full observation, as in training.

The observation is built as the policy was trained: its weights file names the feature set
and the topology settings (information gain kind, D_gain, ...) of its training episodes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from mjexplore.envs.decisions import TerDecisions
from mjexplore.explorers.base import ExplorationState, register, shipped_policy
from mjexplore.policies.weights import actor_logits

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[2] / "training" / "gvn_policy.safetensors"


@register("gvn")
class GvnExplorer:
    """Chooses TER nodes with a GVN policy.

    Args:
        policy: Path of a weights file (default: the shipped ``training/gvn_policy.safetensors``).
        masking: True applies invalid action masking at evaluation (frontier nodes only);
            False is the paper's "masking removed" ablation (any TER node).
        deterministic: Take the most probable node (True) or sample.
    """

    def __init__(self, policy: str | os.PathLike | None = None, masking: bool = True,
                 deterministic: bool = True) -> None:
        from mjexplore.policies.weights import load_policy, weights_sha256

        self.policy, meta = load_policy(policy or DEFAULT_WEIGHTS, expected_kind="gvn")
        self.weights_sha256 = weights_sha256(policy or DEFAULT_WEIGHTS)
        self.gvn = self.policy.features_extractor.gvn
        obs = meta["decisions"].config
        self.decisions = TerDecisions(obs, "frontiers" if masking else "all_nodes",
                                      meta["decisions"].topology)
        self.ter_config = self.decisions.ter_config
        self.memory_length = obs.memory_length
        self.masking = masking
        self.deterministic = deterministic
        self.waypoint = False
        self.reset(np.random.default_rng(0))

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.waypoint = False
        self.decisions.reset()
        self._fragments = torch.zeros(1, self.memory_length, self.gvn.config.hidden)
        self._memory_mask = torch.zeros(1, self.memory_length)

    def logits(self, current: dict[str, np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
        """Node logits (N,; -inf on padding) for the current TER arrays, and the embeddings
        (1, n, d) of the n real nodes.

        Real nodes come first in a padded TER and never point at padding, so only they are
        encoded (padding contributes nothing to a real node's output).
        """
        n = max(int(current["node_mask"].sum()), 1)
        t = {k: torch.as_tensor(v[:n])[None] for k, v in current.items()}
        gvn = self.gvn
        with torch.no_grad():
            r = gvn.spatial(t["node_features"], t["neighbours"], t["node_mask"])
            h = gvn.memory_from_fragments(self._fragments, self._memory_mask)
            z, _ = gvn.fuse(r, t["node_mask"], h)
            real = self.policy.mlp_extractor.actor(z[0]).squeeze(-1)
        logits = torch.full((len(current["node_mask"]),), -torch.inf)
        logits[:n] = real
        return logits, r

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        d = self.decisions
        if not d.prepare(state):
            # Frontiers the TER cannot link (no GVD vertex of the robot's component sees
            # them) are not nodes: the episode's fallback takes the nearest one.
            self.waypoint = False
            return None
        if self.gvn.config.features == "v1":
            logits, r = self.logits(d.current)
        else:
            t = {k: torch.as_tensor(v)[None] for k, v in d.observation().items()}
            with torch.no_grad():
                logits = actor_logits(self.policy, t)[0]
        masked = torch.where(torch.as_tensor(d.mask), logits, torch.tensor(-1e8))
        if self.deterministic:
            action = int(torch.argmax(masked))
        else:
            p = torch.softmax(masked.double(), 0).numpy()
            action = int(self.rng.choice(len(p), p=p / p.sum()))
        if self.gvn.config.features == "v1":
            with torch.no_grad():
                n = r.shape[1]
                frag = self.gvn.fragments(r[0], torch.arange(n),
                                          torch.as_tensor(d.current["node_mask"][:n])[None],
                                          torch.tensor([action]))
            self._fragments = torch.cat([self._fragments[:, 1:], frag[:, None]], 1)
            self._memory_mask = torch.cat([self._memory_mask[:, 1:], torch.ones(1, 1)], 1)
        goal, self.waypoint = d.act(action)
        return goal


def _shipped_weights(name: str) -> Path:
    return shipped_policy(DEFAULT_WEIGHTS.with_name(f"{name}_policy.safetensors"), name)


class _ShippedGvnExplorer(GvnExplorer):
    """A GVN explorer whose default weights are ``training/{weights}_policy.safetensors``,
    run with the mask or without it (``masked``)."""

    weights: str
    masked: bool

    def __init__(self, policy: str | os.PathLike | None = None,
                 deterministic: bool = True) -> None:
        super().__init__(policy or _shipped_weights(self.weights), masking=self.masked,
                         deterministic=deterministic)


@register("gvn_unmasked")
class GvnUnmaskedExplorer(GvnExplorer):
    """The paper's "masking removed" ablation: a policy trained with masking, run without
    it (any TER node may be chosen; padding slots never)."""

    def __init__(self, policy: str | os.PathLike | None = None,
                 deterministic: bool = True) -> None:
        super().__init__(policy, masking=False, deterministic=deterministic)


@register("gvn_naive")
class GvnNaiveExplorer(_ShippedGvnExplorer):
    """The "naive masking" ablation: a policy trained with masked sampling but an unmasked
    gradient (training/gvn_naive.yaml), run with the mask."""

    weights, masked = "gvn_naive", True


@register("gvn_none")
class GvnNoMaskingExplorer(_ShippedGvnExplorer):
    """The "without IAM" ablation: a policy trained with every TER node valid and no mask
    (training/gvn_none.yaml), run the same way."""

    weights, masked = "gvn_none", False


@register("gvn_v2")
class GvnV2Explorer(_ShippedGvnExplorer):
    """The v2 recipe's GVN (training/gvn_v2.yaml: time reward, path-aware features, a
    residual on the nearest-node rule), its shipped weights
    ``training/gvn_v2_policy.safetensors``, run with the mask."""

    weights, masked = "gvn_v2", True


@register("gvn_v3")
class GvnV3Explorer(_ShippedGvnExplorer):
    """The v3 recipe's GVN (training/gvn_v3.yaml: the v2 recipe with each frontier node's
    predicted pocket, mjexplore/topology/pockets.py), its shipped weights
    ``training/gvn_v3_policy.safetensors``, run with the mask."""

    weights, masked = "gvn_v3", True


def _register_masking_variants(recipe: str) -> None:
    """Registers the masking ablation (the paper's Table 2) of a recipe's GVN, ``recipe``
    such as ``gvn_v2``: explorers ``{recipe}_unmasked``, ``{recipe}_naive`` and
    ``{recipe}_none``, classes such as ``GvnV2NaiveExplorer``."""
    for suffix, weights, masked, about in (
            ("unmasked", recipe, False, "masking removed: {r}'s policy run without the mask"),
            ("naive", f"{recipe}_naive", True, "naive masking (training/{r}_naive.yaml: "
             "masked sampling, unmasked gradient), run with the mask"),
            ("none", f"{recipe}_none", False, "without IAM (training/{r}_none.yaml: every "
             "TER node valid, no mask), run the same way")):
        name = f"{recipe}_{suffix}"
        class_name = f"{name.title().replace('_', '')}Explorer"
        # A module attribute, so that pickle finds the class by its name.
        globals()[class_name] = register(name)(type(class_name, (_ShippedGvnExplorer,), {
            "weights": weights, "masked": masked, "__module__": __name__,
            "__doc__": f"The masking ablation of {recipe}, {about.format(r=recipe)}."}))


for _recipe in ("gvn_v2", "gvn_v3"):
    _register_masking_variants(_recipe)
