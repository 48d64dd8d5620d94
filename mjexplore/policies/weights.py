"""Policy weights as safetensors files (no pickle): tensors plus JSON metadata.

A weights file holds the policy's ``state_dict`` and, in the safetensors metadata, the
format tag, the policy's constructor arguments, the observation layout, free-form
provenance (training config, git revision, steps) and ``tensors_sha256``, the sha256 of the
tensors (:func:`tensors_sha256`). Loading one never runs code from it, and checks it: a
file whose tensors do not match their checksum is refused as damaged. The shipped models'
files (``models/NAME/policy.safetensors``, written before the checksum) are checked against
the full-file sha256 their model card names, and so is any copy of one (a file with the
same header).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.io.provenance import file_sha256 as weights_sha256  # noqa: F401 - re-exported
from mjexplore.io.tensor_file import read_tensor_file

if TYPE_CHECKING:
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

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
            "provenance": json.dumps(provenance or {}, default=str),
            "tensors_sha256": tensors_sha256(tensors)}
    write_bytes_atomic(path, save(tensors, metadata=meta))


def tensors_sha256(tensors: dict[str, torch.Tensor]) -> str:
    """The sha256 of a set of tensors: for each in name order, its name, dtype and shape
    (as the JSON ``[name, dtype, shape]``) and its bytes (C order, the machine's byte
    order: little-endian everywhere torch runs)."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        digest.update(json.dumps([name, str(t.dtype).removeprefix("torch."),
                                  list(t.shape)]).encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def _check_intact(path: Path, tensors: dict[str, torch.Tensor], meta: dict[str, str]) -> None:
    """Refuses weights whose tensors do not match their checksum: the file's own
    ``tensors_sha256``, or for a shipped model's file (or a copy of one) its card's sha256.

    Raises:
        UserInputError: the weights are damaged; the message says how to get good ones.
    """
    from mjexplore.policies.models import read_card, shipped_model_of

    stored = meta.get("tensors_sha256")
    if stored is not None:
        if tensors_sha256(tensors) != stored:
            raise UserInputError(
                f"the weights in {str(path)!r} are damaged (their checksum does not match): "
                "re-export them (mjexplore export-policy CHECKPOINT OUT.safetensors) "
                "or take a shipped model ('mjexplore policies' lists them).")
        return
    model = shipped_model_of(path)
    if model is None:
        return  # Written before the checksum, and no card to check it against.
    expected = read_card(model).sha256
    if expected is None:
        return
    actual = hashlib.sha256(path.read_bytes()).hexdigest()
    if actual != expected:
        shipped = f"models/{model}/policy.safetensors"
        fix = (f"restore it with 'git checkout -- {shipped}'"
               if path.resolve().parent.name == model else
               f"take the shipped model (--policy {model}) or copy {shipped} again")
        raise UserInputError(
            f"the weights in {str(path)!r} are damaged (their checksum does not match: sha256 "
            f"{actual[:16]}, where model {model}'s card names {expected[:16]}): {fix}.")


def policy_recipe(path: str | os.PathLike, meta: dict[str, Any]) -> str:
    """What a policy is, for run records: the config it was trained from (a shipped
    model's card names it; a run of 'mjexplore train' keeps it) and its kind, feature set
    and training masking, e.g. 'gvn_v3.yaml (gvn v3, masking iam)'."""
    from mjexplore.policies.models import describe, read_card, shipped_model_of

    what = describe(meta["kind"], meta["layout"], meta["provenance"])
    recipe = meta["provenance"].get("recipe")
    if recipe is None:
        model = shipped_model_of(path)
        recipe = read_card(model).recipe if model is not None else None
    return f"{recipe} ({what})" if recipe else what


def read_policy_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Tensors and decoded metadata of a weights file, checked (see the module docstring).

    Raises:
        UserInputError: missing file, not a safetensors file, truncated, not ours, or
            damaged (tensors that do not match their checksum).
    """
    path = Path(path)
    hint = ("give a .safetensors file written by 'mjexplore train' (e.g. "
            "models/gvn_paper/policy.safetensors).")
    tensors, meta = read_tensor_file(path, "policy weights", hint)
    if meta.get("format") != FORMAT:
        raise UserInputError(f"{str(path)!r} is a safetensors file but not mjexplore policy "
                             f"weights (format {meta.get('format')!r}); {hint}")
    _check_intact(path, tensors, meta)
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
        UserInputError: unreadable or damaged file, another kind of policy (the message
            names the explorer that runs it), or weights that do not fit the network they
            describe.
    """
    from mjexplore.policies.registry import decisions_for

    tensors, meta = read_policy_weights(path)
    if expected_kind is not None and meta["kind"] != expected_kind:
        raise UserInputError(f"{str(path)!r} holds a {meta['kind']} policy, not a "
                             f"{expected_kind} one: run it with --explorer {meta['kind']} "
                             f"--policy {path}.")
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


def actor_logits(policy: MaskableActorCriticPolicy,
                 obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The actor's unmasked logits (B, A) for a batch of observation tensors, whether the
    critic shares the actor's encoder or has its own (``share_features_extractor``; then
    only the actor's runs, as in SB3's ``get_distribution``)."""
    from stable_baselines3.common.policies import BasePolicy

    features = BasePolicy.extract_features(policy, obs, policy.pi_features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))
