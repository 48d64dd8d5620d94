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

import numpy as np
import torch

from mjexplore.envs.decisions import TerDecisions
from mjexplore.episode.explorer import ExplorationState
from mjexplore.policies.models import resolve_policy, run_label, trained_masking
from mjexplore.policies.weights import actor_logits, load_policy, policy_recipe, weights_sha256


class GvnExplorer:
    """Chooses TER nodes with a GVN policy.

    Args:
        policy: A shipped model's name (``models/NAME``), a weights file, or a folder
            holding ``policy.safetensors``; None: the recommended model (``gvn_v3``).
        masking: True applies invalid action masking at evaluation (frontier nodes only);
            False lets it choose any TER node (the paper's "masking removed" ablation);
            None: as the policy was trained (with the mask unless trained without one).
        deterministic: Take the most probable node (True) or sample.
    """

    name = "gvn"

    def __init__(self, policy: str | os.PathLike | None = None, masking: bool | None = None,
                 deterministic: bool = True) -> None:
        self.policy_name, path = resolve_policy(policy, "gvn")
        self.policy, meta = load_policy(path, expected_kind="gvn")
        self.weights_sha256 = weights_sha256(path)
        self.policy_recipe = policy_recipe(path, meta)  # For run records (metrics.json).
        trained = trained_masking(meta["provenance"])
        if masking is None:
            masking = trained != "none"
        self.label = run_label("gvn", self.policy_name, masking, trained)
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
        current = d.current
        assert current is not None  # Set by prepare().
        if self.gvn.config.features == "v1":
            logits, r = self.logits(current)
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
                                          torch.as_tensor(current["node_mask"][:n])[None],
                                          torch.tensor([action]))
            self._fragments = torch.cat([self._fragments[:, 1:], frag[:, None]], 1)
            self._memory_mask = torch.cat([self._memory_mask[:, 1:], torch.ones(1, 1)], 1)
        choice = d.act(action)
        assert choice is not None  # A masked-in action is a real node.
        goal, self.waypoint = choice
        return goal
