"""The GVN as a stable-baselines3 / sb3-contrib policy with invalid action masking.

:class:`GvnPolicy` subclasses sb3-contrib's ``MaskableActorCriticPolicy``: the features
extractor runs the :class:`~mjexplore.policies.gvn.GVN`, the actor head gives one logit per
TER node (the default head, a ``Linear(latent, N)``, would tie logits to node slots), and
the critic head reads the pooled node features (and, with an observation that carries
them, the ground-truth ``privileged`` inputs: an asymmetric actor-critic, whose actor
does not read them).

With ``prior_temperature`` set (v2 observations), the actor's logits are the nearest-node
rule's (:func:`~mjexplore.policies.gvn.path_prior`: minus the path length to each node)
plus the network's: a residual policy. Its head starting near zero, the policy starts as
nearest-frontier (greedy) and PPO learns where to depart from it.

Masking modes (paper Table 2):

* ``iam``: invalid action masking (Eq. 14-15): invalid logits are replaced by -1e8 when
  sampling and in the PPO loss, so their gradients are zero.
* ``naive``: the mask is applied when sampling only; log-probabilities, the PPO ratio and
  the entropy use the unmasked distribution over real nodes, so invalid logits do get
  gradients.
* ``none``: no masking by the policy (train it on an env with
  ``valid_actions='all_nodes'``, where every real node is an action).

"Masking removed" is an evaluation-time choice (a policy trained with ``iam`` run without
the mask), made by the GVN explorer.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import torch
from gymnasium import spaces
from sb3_contrib.common.maskable.distributions import MaskableCategorical
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from mjexplore.envs.observation import POCKET
from mjexplore.policies.gvn import GVN, GvnConfig, path_prior, tracing

MASKING_MODES = ("iam", "naive", "none")
ENTROPY_REFERENCES = ("uniform", "prior")


class GvnExtractor(BaseFeaturesExtractor):
    """Observation dict -> flat [z (N d), pooled (2 d)] features, then with
    ``prior_temperature`` the nearest-node prior's logits (N), then the observation's
    ``privileged`` entry when it has one (for the critic only).

    The network's feature set follows the observation's: a ``memory_pose`` entry means the
    ``v2`` observation, and so the v2 network.
    """

    def __init__(self, observation_space: spaces.Dict, hidden: int = 64, gcn_layers: int = 3,
                 tcn_kernel: int = 3, tcn_dilations: tuple[int, ...] = (1, 2, 4),
                 attention_layers: int = 1, attention_heads: int = 4,
                 prior_temperature: float | None = None, prior_pocket_m: float = 0.0) -> None:
        n = cast(spaces.Box, observation_space["node_mask"]).shape[0]
        prior = n if prior_temperature is not None else 0
        privileged = privileged_size(observation_space)
        super().__init__(observation_space,
                         features_dim=n * hidden + 2 * hidden + prior + privileged)
        self.privileged = privileged > 0
        self.num_nodes = n
        features = "v2" if "memory_pose" in observation_space.spaces else "v1"
        if prior_temperature is not None and (features != "v2" or prior_temperature <= 0):
            raise ValueError("prior_temperature needs the v2 observation (its path "
                             "feature) and must be > 0 (metres)")
        num_features = cast(spaces.Box, observation_space["node_features"]).shape[0] // n
        if prior_pocket_m and (not prior or num_features <= POCKET):
            raise ValueError("prior_pocket_m needs prior_temperature and the v3 observation "
                             "(its pocket feature)")
        self.prior_temperature = prior_temperature
        self.prior_pocket_m = prior_pocket_m
        self.gvn = GVN(GvnConfig(hidden=hidden, gcn_layers=gcn_layers, tcn_kernel=tcn_kernel,
                                 tcn_dilations=tuple(tcn_dilations), features=features,
                                 attention_layers=attention_layers,
                                 attention_heads=attention_heads),
                       num_features=num_features)

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        z, pooled = self.gvn(observations)
        parts = [z.flatten(1), pooled]
        prior = self.prior_logits(observations)
        if prior is not None:
            parts.append(prior)
        if self.privileged:  # Passed through for the critic (GvnHeads).
            parts.append(observations["privileged"])
        return torch.cat(parts, -1)

    def prior_logits(self, observations: dict[str, torch.Tensor]) -> torch.Tensor | None:
        """The nearest-node prior's logits (B, N) of batched flat observations (None
        without ``prior_temperature``)."""
        if self.prior_temperature is None:
            return None
        features = observations["node_features"]
        return path_prior(features.reshape(len(features), self.num_nodes, -1),
                          self.prior_temperature, self.prior_pocket_m)


def privileged_size(observation_space: spaces.Dict) -> int:
    """Ground-truth critic inputs in an observation space (0 without a ``privileged``
    entry; see :mod:`mjexplore.envs.observation`)."""
    space = observation_space.spaces.get("privileged")
    return 0 if space is None else int(cast(spaces.Box, space).shape[0])


class GvnHeads(nn.Module):
    """Actor (one logit per node, plus the prior's when the features carry one) and critic
    (the pooled node features, and the ground-truth inputs when the features carry them)
    trunks over :class:`GvnExtractor` features. The actor never reads the ground truth."""

    def __init__(self, num_nodes: int, hidden: int, prior: bool = False,
                 privileged: int = 0, residual_scale: float = 1.0) -> None:
        super().__init__()
        self.num_nodes, self.hidden, self.prior = num_nodes, hidden, prior
        self.residual_scale = residual_scale
        self.privileged = privileged
        self.latent_dim_pi = num_nodes
        self.latent_dim_vf = hidden
        self.actor = nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))
        self.critic = nn.Sequential(nn.Linear(2 * hidden + privileged, hidden), nn.ReLU())

    def _split(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor,
                                                       torch.Tensor | None]:
        """(z (B, N, d), pooled (B, 2 d), the prior's logits (B, N) or None); the
        ground-truth inputs, when present, are the last ``privileged`` features."""
        n, d = self.num_nodes, self.hidden
        z = features[:, :n * d].reshape(-1, n, d)
        pooled = features[:, n * d:n * d + 2 * d]
        prior = features[:, n * d + 2 * d:n * d + 2 * d + n] if self.prior else None
        return z, pooled, prior

    def node_logits(self, z: torch.Tensor) -> torch.Tensor:
        """The actor's logit of each node (B, N) from node features z (B, N, d).

        Where gradients are taken (PPO's update), every row of z that is all zero (each
        padding slot, about half a batch's slots, and any node whose features are all
        zero) has the same logit, computed once, and the actor's MLP runs on the other
        rows only. Inference runs it on every row, as it always did.
        """
        if tracing() or not torch.is_grad_enabled():
            return self.actor(z).squeeze(-1)
        b, n, d = z.shape
        flat = z.reshape(b * n, d)
        live = flat.ne(0).any(-1).nonzero().squeeze(1)
        zero = self.actor(flat.new_zeros(1, d))
        return zero.expand(b * n, 1).index_copy(
            0, live, self.actor(flat.index_select(0, live))).view(b, n)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        z, _, prior = self._split(features)
        logits = self.node_logits(z)
        if self.residual_scale != 1.0:
            logits = self.residual_scale * logits
        return logits if prior is None else logits + prior

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        pooled = self._split(features)[1]
        if self.privileged:
            pooled = torch.cat([pooled, features[:, -self.privileged:]], -1)
        return self.critic(pooled)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)


class GvnPolicy(MaskableActorCriticPolicy):
    """MaskablePPO policy with the GVN.

    The actor's last layer starts orthogonal with gain ``actor_gain`` (0.01, the gain SB3
    gives its own action head) and zero bias, so the initial policy is near uniform over
    the valid nodes; SB3's ``ortho_init`` would give it sqrt(2) as part of the MLP trunk.

    Args:
        masking: 'iam', 'naive' or 'none' (see the module docstring).
        hidden, gcn_layers, tcn_kernel, tcn_dilations, attention_layers, attention_heads:
            :class:`GvnConfig` sizes (attention: v2 observations only).
        actor_gain: Initial gain of the logit layer (applied with ``ortho_init``).
        prior_temperature: Metres per nat of the nearest-node prior added to the actor's
            logits (v2 or v3 observations; None: no prior). See the module docstring.
        prior_pocket_m: v3: metres the prior adds per unit of a node's pocket probability
            (:func:`~mjexplore.policies.gvn.path_prior`; 0: none).
        residual_scale: Nats per unit of the network's output added to the prior's logits.
            Departures from the v3 prior that the oracle asks for are mostly a pocket's
            weight (median 31 m at 1 m per nat); the head grows to tens of units only over
            many steps, so a residual policy can start on the same scale as its prior.
        entropy_reference: ``uniform`` (the default): :meth:`evaluate_actions` gives the
            policy's entropy over the valid actions, as SB3's policies do. ``prior`` (needs
            ``prior_temperature``): it gives the entropy relative to the prior,
            ``-KL(policy || prior)`` over the valid actions, so that PPO's entropy bonus
            ``ent_coef`` becomes a pull toward the prior (KL-regularised RL toward a
            behaviour prior, as in Tirumala et al. 2019 or RLHF's reference policy): the
            policy departs from its prior only where the advantages keep asking for it.
            Only the update reads it.
        Other arguments as ``MaskableActorCriticPolicy``.
    """

    # SB3 types it as its own MlpExtractor; custom heads are its documented extension.
    mlp_extractor: GvnHeads  # type: ignore[assignment]

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.Discrete,
                 lr_schedule, masking: str = "iam", hidden: int = 64, gcn_layers: int = 3,
                 tcn_kernel: int = 3, tcn_dilations: tuple[int, ...] = (1, 2, 4),
                 attention_layers: int = 1, attention_heads: int = 4,
                 actor_gain: float = 0.01, prior_temperature: float | None = None,
                 prior_pocket_m: float = 0.0, residual_scale: float = 1.0,
                 entropy_reference: str = "uniform", **kwargs: Any) -> None:
        if masking not in MASKING_MODES:
            raise ValueError(f"masking must be one of {MASKING_MODES}, not {masking!r}")
        if entropy_reference not in ENTROPY_REFERENCES:
            raise ValueError(f"entropy_reference must be one of {ENTROPY_REFERENCES}, not "
                             f"{entropy_reference!r}")
        if entropy_reference == "prior" and prior_temperature is None:
            raise ValueError("entropy_reference 'prior' needs prior_temperature (a prior)")
        self.masking = masking
        self.hidden = hidden
        self.actor_gain = actor_gain
        kwargs.setdefault("features_extractor_class", GvnExtractor)
        kwargs.setdefault("features_extractor_kwargs", dict(
            hidden=hidden, gcn_layers=gcn_layers, tcn_kernel=tcn_kernel,
            tcn_dilations=tuple(tcn_dilations), attention_layers=attention_layers,
            attention_heads=attention_heads, prior_temperature=prior_temperature,
            prior_pocket_m=prior_pocket_m))
        self.prior_temperature = prior_temperature
        self._gvn_kwargs = dict(masking=masking, hidden=hidden, gcn_layers=gcn_layers,
                                tcn_kernel=tcn_kernel, tcn_dilations=tuple(tcn_dilations),
                                attention_layers=attention_layers,
                                attention_heads=attention_heads, actor_gain=actor_gain,
                                prior_temperature=prior_temperature,
                                prior_pocket_m=prior_pocket_m)
        if residual_scale != 1.0:  # Stored with the weights only when it differs.
            self._gvn_kwargs["residual_scale"] = residual_scale
        self.residual_scale = residual_scale
        if entropy_reference != "uniform":
            self._gvn_kwargs["entropy_reference"] = entropy_reference
        self.entropy_reference = entropy_reference
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(self._gvn_kwargs)
        return data

    def _build_mlp_extractor(self) -> None:
        action_space = cast(spaces.Discrete, self.action_space)  # As passed to __init__.
        self.mlp_extractor = GvnHeads(int(action_space.n), self.hidden,
                                      prior=self.prior_temperature is not None,
                                      privileged=privileged_size(
                                          cast(spaces.Dict, self.observation_space)),
                                      residual_scale=self.residual_scale)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # The actor's logits come out of GvnHeads already (one per node).
        self.action_net = nn.Identity()
        if self.ortho_init:
            logit_layer = cast(nn.Linear, self.mlp_extractor.actor[-1])  # See GvnHeads.
            nn.init.orthogonal_(logit_layer.weight, gain=self.actor_gain)
            nn.init.zeros_(logit_layer.bias)
        # SB3 types optimizer_class as the bare Optimizer, without lr (its _build ignores it).
        self.optimizer = self.optimizer_class(self.parameters(),  # type: ignore[call-arg]
                                              lr=lr_schedule(1), **self.optimizer_kwargs)

    def _real_nodes(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return obs["node_mask"] > 0

    def forward(self, obs, deterministic: bool = False, action_masks: np.ndarray | None = None):
        if self.masking != "naive":
            return super().forward(obs, deterministic, action_masks)
        features = self.extract_features(obs)
        if self.share_features_extractor:
            latent_pi, latent_vf = self.mlp_extractor(features)
        else:
            latent_pi = self.mlp_extractor.forward_actor(features[0])
            latent_vf = self.mlp_extractor.forward_critic(features[1])
        values = self.value_net(latent_vf)
        distribution = self._get_action_dist_from_latent(latent_pi)
        if action_masks is not None:
            distribution.apply_masking(action_masks)
        actions = distribution.get_actions(deterministic=deterministic)
        distribution.apply_masking(self._real_nodes(obs))  # Gradient path: unmasked logits.
        return actions, values, distribution.log_prob(actions)

    def evaluate_actions(self, obs, actions: torch.Tensor,
                         action_masks: torch.Tensor | None = None):
        if self.masking == "naive":
            action_masks = self._real_nodes(obs)
        if self.entropy_reference == "uniform":
            return super().evaluate_actions(obs, actions, action_masks)
        # The actor's and the critic's passes apart (each its own encoder in the recipes,
        # so no work is repeated), the prior read off the observation.
        # sb3-contrib types the masks as an ndarray; it takes tensors too (th.as_tensor).
        distribution = self.get_distribution(obs, action_masks)  # type: ignore[arg-type]
        values = self.predict_values(obs)
        extractor = cast(GvnExtractor, self.pi_features_extractor)  # features_extractor_class
        prior = extractor.prior_logits(obs)
        assert prior is not None  # entropy_reference 'prior' needs prior_temperature.
        categorical = cast(MaskableCategorical, distribution.distribution)  # Discrete actions.
        relative = -kl_to_prior(categorical.logits, prior, categorical.masks)
        return values, distribution.log_prob(actions), relative


def kl_to_prior(log_probs: torch.Tensor, prior_logits: torch.Tensor,
                valid: torch.Tensor | None) -> torch.Tensor:
    """KL(policy || prior) in nats over the valid actions, the prior renormalised on them.

    Args:
        log_probs: (B, A) the policy's normalised log-probabilities (masked actions at
            about -1e8, as sb3-contrib's masked distribution holds them).
        prior_logits: (B, A) the prior's logits.
        valid: (B, A) bool, the valid actions (None: all).

    Returns:
        (B,) the divergence, >= 0 (clamped: where every valid logit lies near the excluded
        nodes' -4e4 / temperature, float32 keeps only steps of about 1e-2 nats and the sum
        can come out a little below 0).
    """
    if valid is None:
        valid = torch.ones_like(log_probs, dtype=torch.bool)
    log_prior = torch.log_softmax(prior_logits.masked_fill(~valid, -torch.inf), -1)
    # Masked before the product: exp(-1e8) * inf would send NaN down the gradient.
    gap = torch.where(valid, log_probs - log_prior, torch.zeros_like(log_probs))
    return (log_probs.exp() * gap).sum(-1).clamp_min(0.0)
