"""Policy weights as safetensors files (no pickle): tensors plus JSON metadata.

A weights file holds the policy's ``state_dict`` and, in the safetensors metadata, the
format tag, the policy's constructor arguments, the observation layout and free-form
provenance (training config, git revision, steps). Loading one never runs code from it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.io.provenance import file_sha256 as weights_sha256  # noqa: F401 - re-exported
from mjexplore.io.tensor_file import read_tensor_file

FORMAT = "mjexplore-policy-v1"
ALIASES = ("pi_features_extractor.", "vf_features_extractor.")


def save_policy_weights(path: str | os.PathLike, policy: torch.nn.Module, kind: str,
                        policy_kwargs: dict[str, Any], layout: dict[str, Any],
                        provenance: dict[str, Any] | None = None) -> None:
    """Writes ``policy``'s weights atomically; ``layout`` is the decision space's config
    (see :mod:`mjexplore.policies.registry`)."""
    from safetensors.torch import save

    tensors, seen = {}, set()
    for k, v in policy.state_dict().items():
        # SB3 keeps aliases of the shared features extractor (pi_/vf_); store each once.
        if v.data_ptr() in seen and v.numel():
            continue
        seen.add(v.data_ptr())
        tensors[k] = v.detach().cpu().contiguous()
    meta = {"format": FORMAT, "kind": kind, "policy_kwargs": json.dumps(policy_kwargs),
            "layout": json.dumps(layout),
            "provenance": json.dumps(provenance or {}, default=str)}
    write_bytes_atomic(path, save(tensors, metadata=meta))


def read_policy_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Tensors and decoded metadata of a weights file.

    Raises:
        UserInputError: missing file, not a safetensors file, truncated, or not ours.
    """
    path = Path(path)
    hint = ("give a .safetensors file written by 'mjexplore train' (e.g. "
            "models/gvn_paper/policy.safetensors).")
    tensors, meta = read_tensor_file(path, "policy weights", hint)
    if meta.get("format") != FORMAT:
        raise UserInputError(f"{str(path)!r} is a safetensors file but not mjexplore policy "
                             f"weights (format {meta.get('format')!r}); {hint}")
    try:
        decoded = {"kind": meta["kind"], "policy_kwargs": json.loads(meta["policy_kwargs"]),
                   "layout": json.loads(meta["layout"]),
                   "provenance": json.loads(meta.get("provenance", "{}"))}
    except (KeyError, TypeError, ValueError) as exc:
        raise UserInputError(f"{str(path)!r} has damaged metadata ({exc}); {hint}") from None
    return tensors, decoded


def build_policy(kind: str, observation_space, action_space, policy_kwargs: dict[str, Any]):
    """A fresh policy network of ``kind`` for inference (no learning-rate schedule)."""
    from mjexplore.policies.registry import policy_class

    return policy_class(kind)(observation_space, action_space, lambda _: 0.0, **policy_kwargs)


def load_policy(path: str | os.PathLike, expected_kind: str | None = None):
    """Rebuilds the policy stored at ``path`` in evaluation mode.

    Returns:
        (policy, metadata); ``metadata["decisions"]`` is the policy's decision space.

    Raises:
        UserInputError: unreadable file, another kind of policy, or weights that do not
            fit the network they describe.
    """
    from mjexplore.policies.registry import decisions_for

    tensors, meta = read_policy_weights(path)
    if expected_kind is not None and meta["kind"] != expected_kind:
        raise UserInputError(f"{str(path)!r} holds a {meta['kind']!r} policy, not "
                             f"{expected_kind!r}: pick the matching --explorer.")
    decisions = decisions_for(meta["kind"], meta["layout"])
    meta["decisions"] = decisions
    try:
        policy = build_policy(meta["kind"], decisions.observation_space, decisions.action_space,
                              meta["policy_kwargs"])
    except (TypeError, ValueError) as exc:
        raise UserInputError(f"{str(path)!r} describes a network this version cannot build "
                             f"({exc}).") from None
    problem = None
    try:
        result = policy.load_state_dict(tensors, strict=False)
        missing = [k for k in result.missing_keys if not k.startswith(ALIASES)]
        if missing or result.unexpected_keys:
            problem = f"missing {missing[:3]}, unexpected {result.unexpected_keys[:3]}"
    except RuntimeError as exc:
        problem = str(exc).splitlines()[0]
    if problem:
        raise UserInputError(f"weights in {str(path)!r} do not fit the network they describe "
                             f"({problem}); the file is damaged or from another version.")
    policy.set_training_mode(False)
    return policy, meta


def actor_logits(policy: torch.nn.Module, obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The actor's unmasked logits (B, A) for a batch of observation tensors, whether the
    critic shares the actor's encoder or has its own (``share_features_extractor``; then
    only the actor's runs, as in SB3's ``get_distribution``)."""
    from stable_baselines3.common.policies import BasePolicy

    features = BasePolicy.extract_features(policy, obs, policy.pi_features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))
