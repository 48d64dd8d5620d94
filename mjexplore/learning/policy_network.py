"""The policy network a training config describes: its keyword arguments (what weights files
record with the tensors) and a fresh network for inference."""

from __future__ import annotations

from typing import Any

from mjexplore.learning.train_config import TrainConfig
from mjexplore.policies.registry import layout_of
from mjexplore.policies.weights import build_policy


def network_kwargs(config: TrainConfig) -> dict[str, Any]:
    """The keyword arguments of ``config``'s policy network (SB3's ``policy_kwargs``, as
    weights files record them): the settings of its kind only, and the optional ones only
    where they differ from their defaults."""
    p = config.policy
    if config.kind == "cnn":
        return dict(masking=p.masking, features=p.features)
    kwargs = dict(masking=p.masking, hidden=p.hidden, gcn_layers=p.gcn_layers,
                  tcn_kernel=p.tcn_kernel, tcn_dilations=list(p.tcn_dilations))
    if not p.share_features_extractor:  # Stored with the weights only when it differs.
        kwargs["share_features_extractor"] = False
    if p.prior_temperature is not None:
        kwargs["prior_temperature"] = p.prior_temperature
    if p.prior_pocket_m:
        kwargs["prior_pocket_m"] = p.prior_pocket_m
    if p.residual_scale != 1.0:
        kwargs["residual_scale"] = p.residual_scale
    return kwargs


def fresh_policy(config: TrainConfig):
    """A new policy network of ``config`` for inference."""
    from mjexplore.policies.registry import decisions_for

    decisions = decisions_for(config.kind, layout_of(config.kind, config.env))
    return build_policy(config.kind, decisions.observation_space, decisions.action_space,
                        network_kwargs(config))
