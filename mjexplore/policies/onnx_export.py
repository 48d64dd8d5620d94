"""A trained policy's actor as an ONNX model, and running it with onnxruntime.

The exported graph takes one decision's observation arrays, exactly as the env and the
explorers build them (:mod:`mjexplore.envs.observation` for the GVN: the padded TER and
the raw episodic memory; :class:`~mjexplore.envs.decisions.GridDecisions` for the CNN: the
map image), each flat with a leading batch axis, and the boolean action mask; it returns
the masked action logits (invalid actions at :data:`MASKED_LOGIT`, as sb3-contrib masks
them) and the greedy action. The critic is left out: deployment needs only the actor.

The GVN's spatial encoder multiplies by a sparse adjacency of the real nodes in torch,
which ONNX cannot express; the exported graph computes the same GCN over the same real
nodes with row gathers along the padded neighbour slots, using the same weights.

The model's ``metadata_props`` hold the format tag, the policy kind, the SHA-256 of the
weights file it came from, the input names in order with their per-decision shapes and
dtypes, the decision-space layout, the policy's constructor arguments and the weights'
provenance.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic
from mjexplore.policies.gvn import (
    GVN,
    GraphConv,
    SpatialEncoder,
    masked_mean,
    memory_pose_features,
)
from mjexplore.policies.weights import actor_logits, load_policy
from mjexplore.topology.ter import NUM_FEATURES

if TYPE_CHECKING:
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

    from mjexplore.policies.sb3 import GvnExtractor

log = logging.getLogger(__name__)

FORMAT = "mjexplore-policy-onnx-v1"
MASKED_LOGIT = -1.0e8  # sb3-contrib's MaskableCategorical value for invalid actions.
OPSET = 18


def spatial_gather(encoder: SpatialEncoder, features: torch.Tensor, neighbours: torch.Tensor,
                   node_mask: torch.Tensor) -> torch.Tensor:
    """:meth:`SpatialEncoder.forward` with row gathers instead of a sparse adjacency.

    As in torch, only the R real nodes are encoded. Row i of A_norm H W is
    inv_i^2 (HW)_i + the sum over i's neighbour slots holding a real node j of
    inv_i inv_j (HW)_j, where inv = (1 + occupied slots)^-1/2 (an edge to padding counts in
    the degree but joins nothing, as in :func:`~mjexplore.policies.gvn.normalized_adjacency`).
    A node's place among the real rows is a running count, so that no tensor is filled with
    a value that depends on the data (which ONNX export cannot trace).

    Args:
        encoder: The trained spatial encoder (its weights are used as they are).
        features: (M, N, 6) node features.
        neighbours: (M, N, K) neighbour indices, -1 for an empty slot.
        node_mask: (M, N) 1 for real nodes.

    Returns:
        (M, N, d) node embeddings, zero on padding.
    """
    m, n, k = neighbours.shape
    real = node_mask.reshape(m * n) > 0
    real_rows = real.nonzero().squeeze(1)
    # 1-based place of each slot among the real rows, 0 for padding: row 0 of the padded
    # embeddings below is zeros.
    place = torch.where(real, real.long().cumsum(0), torch.zeros((), dtype=torch.long))
    slots = neighbours.reshape(m * n, k).index_select(0, real_rows).long()
    edge = slots >= 0
    target = place[((real_rows // n)[:, None] * n + slots.clamp(min=0)).reshape(-1)]
    target = torch.where(edge.reshape(-1), target, torch.zeros((), dtype=torch.long))
    inv = (1.0 + edge.sum(-1).to(features.dtype)).rsqrt()
    weight = inv[:, None] * torch.cat([inv.new_zeros(1), inv])[target].reshape(-1, k)
    h = features.reshape(m * n, NUM_FEATURES).index_select(0, real_rows) * encoder.scale
    for i, layer in enumerate(encoder.layers):
        skip = encoder.input_skip(h) if i == 0 else h
        hw = cast(GraphConv, layer).weight(h)  # The layers of a v1 SpatialEncoder.
        d = hw.shape[-1]
        messages = torch.cat([hw.new_zeros(1, d), hw])[target].reshape(-1, k, d)
        h = F.relu(inv.square()[:, None] * hw + (weight[..., None] * messages).sum(1)) + skip
    return h.new_zeros(m * n, h.shape[-1]).index_copy(0, real_rows, h).reshape(m, n, -1)


def _all_ters(obs: dict[str, torch.Tensor], f: int) -> tuple[torch.Tensor, ...]:
    """The current TER and the E remembered ones of B observations, as one batch of
    B (E + 1) graphs: features (., N, f), neighbours (., N, K), node mask (., N)."""
    b, n = obs["node_mask"].shape
    e = obs["memory_mask"].shape[-1]
    k = obs["neighbours"].shape[-1] // n
    features = torch.cat([obs["node_features"].reshape(b, 1, n, f),
                          obs["memory_node_features"].reshape(b, e, n, f)], 1)
    neighbours = torch.cat([obs["neighbours"].reshape(b, 1, n, k),
                            obs["memory_neighbours"].reshape(b, e, n, k)], 1)
    node_mask = torch.cat([obs["node_mask"].reshape(b, 1, n),
                           obs["memory_node_mask"].reshape(b, e, n)], 1)
    return (features.reshape(b * (e + 1), n, f), neighbours.reshape(b * (e + 1), n, k),
            node_mask.reshape(b * (e + 1), n))


def _remembered(r: torch.Tensor, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """The fragments' mean node embedding and chosen node's embedding (B E, d) of the
    remembered TERs, from the embeddings r (B, E + 1, N, d) of :func:`_all_ters`."""
    b, _, n, d = r.shape
    e = obs["memory_mask"].shape[-1]
    remembered = r[:, 1:].reshape(b * e, n, d)
    choice = obs["memory_choice"].reshape(b * e).long().clamp(0, n - 1)
    chosen = torch.gather(remembered, 1, choice[:, None, None].expand(b * e, 1, d))[:, 0]
    return masked_mean(remembered, obs["memory_node_mask"].reshape(b * e, n)), chosen


def gvn_v2_features(gvn: GVN, obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """:func:`gvn_features` of a v2 network: its encoder exports as it is; every TER of the
    batch is encoded (no search for repeated ones) and attention runs over all N slots
    (padding masked) rather than up to the batch's last real node."""
    b, n = obs["node_mask"].shape
    e = obs["memory_mask"].shape[-1]
    f = obs["node_features"].shape[-1] // n
    r = gvn.spatial(*_all_ters(obs, f)).reshape(b, e + 1, n, -1)
    mean, chosen = _remembered(r, obs)
    place = memory_pose_features(obs["memory_pose"].reshape(b, e, 3),
                                 obs["memory_node_features"].reshape(b, e, n, f),
                                 obs["memory_choice"].reshape(b, e)).reshape(b * e, -1)
    fragments = gvn.fragment(torch.cat([mean, chosen, place], -1)).reshape(b, e, -1)
    h = gvn.memory_from_fragments(fragments, obs["memory_mask"])
    attended = gvn.attend_dense(r[:, 0], obs["node_mask"] > 0, h)
    z, pooled = gvn.fuse(attended, obs["node_mask"], h)
    return torch.cat([z.flatten(1), pooled], -1)


def gvn_features(gvn: GVN, obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The :class:`~mjexplore.policies.sb3.GvnExtractor` features [z (N d), pooled (2 d)]
    of batched flat observations, computed with :func:`spatial_gather` (v1) or
    :func:`gvn_v2_features`."""
    if gvn.config.features == "v2":
        return gvn_v2_features(gvn, obs)
    b, n = obs["node_mask"].shape
    e = obs["memory_mask"].shape[-1]
    r = spatial_gather(gvn.spatial, *_all_ters(obs, NUM_FEATURES)).reshape(b, e + 1, n, -1)
    mean, chosen = _remembered(r, obs)
    fragments = gvn.fragment(torch.cat([mean, chosen], -1)).reshape(b, e, -1)
    z, pooled = gvn.fuse(r[:, 0], obs["node_mask"], gvn.memory_from_fragments(
        fragments, obs["memory_mask"]))
    return torch.cat([z.flatten(1), pooled], -1)


class ExportedActor(nn.Module):
    """A trained SB3 policy's actor: (observation arrays..., action mask) -> (masked
    logits, greedy action). Inputs are positional, in ``keys`` order, then the mask."""

    def __init__(self, policy: MaskableActorCriticPolicy, kind: str, keys: list[str]) -> None:
        super().__init__()
        self.policy = policy
        self.kind = kind
        self.keys = keys

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        *arrays, action_mask = inputs
        obs = dict(zip(self.keys, arrays))
        policy = self.policy
        if self.kind == "gvn":
            extractor = cast("GvnExtractor", policy.features_extractor)  # GvnPolicy's.
            features = gvn_features(extractor.gvn, obs)
            prior = extractor.prior_logits(obs)
            if prior is not None:  # A residual policy (GvnExtractor's last features).
                features = torch.cat([features, prior], -1)
        else:
            features = policy.features_extractor(obs)
        logits = policy.action_net(policy.mlp_extractor.forward_actor(features))
        masked = torch.where(action_mask, logits, torch.full_like(logits, MASKED_LOGIT))
        return masked, masked.argmax(-1)


def file_sha256(path: str | os.PathLike) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def actor_signature(meta: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Input name -> per-decision shape and dtype, in the order the model takes them."""
    decisions = meta["decisions"]
    inputs = {key: {"shape": list(space.shape), "dtype": "float32"}
              for key, space in decisions.observation_space.spaces.items()
              if key != "privileged"}  # The critic's ground truth; the actor reads none.
    inputs["action_mask"] = {"shape": [int(decisions.action_space.n)], "dtype": "bool"}
    return inputs


def example_inputs(signature: dict[str, dict[str, Any]], batch: int = 1) -> tuple:
    """Zero inputs of the signature's shapes (neighbour slots empty, every action valid)."""
    arrays = []
    for key, spec in signature.items():
        if spec["dtype"] == "bool":
            arrays.append(torch.ones(batch, *spec["shape"], dtype=torch.bool))
        else:
            fill = -1.0 if "neighbours" in key else 0.0
            arrays.append(torch.full((batch, *spec["shape"]), fill))
    return tuple(arrays)


def export_onnx(weights: str | os.PathLike, out: str | os.PathLike,
                opset: int = OPSET) -> dict[str, str]:
    """Writes the actor of the policy in ``weights`` (a safetensors file of
    :mod:`mjexplore.policies.weights`) as an ONNX model at ``out``, atomically.

    The batch axis is dynamic. Returns the metadata stored in the model.

    Raises:
        UserInputError: the weights file is unreadable or not an mjexplore policy.
    """
    import onnx

    policy, meta = load_policy(weights)
    signature = actor_signature(meta)
    keys = [k for k in signature if k != "action_mask"]
    actor = ExportedActor(policy, meta["kind"], keys).eval()
    batch = torch.export.Dim("batch", min=1)
    # The exporter's known, harmless chatter: torchvision ops it skips registering, a
    # deprecation inside torch.export, and one shared batch axis named once.
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)
    # torch.export prints the partial graph of a capture strategy that fails (18 KB for the
    # v3 GVN) before the exporter falls back to the next one: kept for -v, not shown.
    chatter = io.StringIO()
    try:
        with (torch.no_grad(), warnings.catch_warnings(), contextlib.redirect_stderr(chatter),
              contextlib.redirect_stdout(chatter)):
            warnings.filterwarnings("ignore", r"`isinstance\(treespec, LeafSpec\)`",
                                    FutureWarning)
            warnings.filterwarnings("ignore", r"# The axis name: batch", UserWarning)
            # A batch of 2 in the example: torch.export fixes axes it sees with size 1.
            program = torch.onnx.export(
                actor, example_inputs(signature, 2), dynamo=True, opset_version=opset,
                input_names=list(signature), output_names=["masked_logits", "action"],
                dynamic_shapes=(tuple({0: batch} for _ in signature),), verbose=False)
    finally:
        registration.setLevel(level)
        if chatter.getvalue():
            log.debug("the ONNX exporter's output:\n%s", chatter.getvalue())
    assert program is not None  # dynamo=True always returns the program.
    model = program.model_proto
    props = {"format": FORMAT, "kind": meta["kind"],
             "weights_file": Path(weights).name, "weights_sha256": file_sha256(weights),
             "observation_keys": json.dumps(keys), "inputs": json.dumps(signature),
             "outputs": json.dumps({"masked_logits": "float32 (batch, actions); invalid "
                                    f"actions at {MASKED_LOGIT:g}",
                                    "action": "int64 (batch,), argmax of masked_logits"}),
             "masked_logit": repr(MASKED_LOGIT), "layout": json.dumps(meta["layout"]),
             "policy_kwargs": json.dumps(meta["policy_kwargs"]),
             "provenance": json.dumps(meta["provenance"], default=str),
             "torch_version": torch.__version__}
    onnx.helper.set_model_props(model, props)
    onnx.checker.check_model(model)
    write_bytes_atomic(out, model.SerializeToString())
    return props


class OnnxActor:
    """An exported actor run with onnxruntime on the CPU.

    Args:
        path: The ``.onnx`` file written by :func:`export_onnx`.
        threads: onnxruntime intra-op threads (1: one core per decision).
    """

    def __init__(self, path: str | os.PathLike, threads: int = 1) -> None:
        import onnx
        import onnxruntime as ort
        from google.protobuf.message import DecodeError

        try:
            model = onnx.load(str(path), load_external_data=False)
        except (OSError, DecodeError) as exc:
            raise UserInputError(f"cannot read ONNX model {str(path)!r} ({exc}); export one "
                                 "with 'mjexplore export-policy --onnx'.") from None
        self.metadata = {p.key: p.value for p in model.metadata_props}
        if self.metadata.get("format") != FORMAT:
            raise UserInputError(f"{str(path)!r} is not an mjexplore policy export (format "
                                 f"{self.metadata.get('format')!r}).")
        self.keys = json.loads(self.metadata["observation_keys"])
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(model.SerializeToString(), options,
                                            providers=["CPUExecutionProvider"])

    def __call__(self, obs: dict[str, np.ndarray], action_mask: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Masked logits (B, A) and greedy actions (B,) of one decision's (or a batch's)
        observation arrays; unbatched arrays get a batch axis of 1.

        Raises:
            UserInputError: ``obs`` lacks arrays the model takes, or their shapes differ
                from the model's.
        """
        batched = np.ndim(action_mask) == 2
        missing = [k for k in self.keys if k not in obs]
        if missing:
            raise UserInputError(
                f"the observation lacks {', '.join(missing)}: this model takes "
                f"{', '.join(self.keys)} (its policy's layout; the observation holds "
                f"{', '.join(sorted(obs)) or 'nothing'}). Build the observation with the "
                "decision space of the policy the model was exported from.")
        feed = {k: np.asarray(obs[k], np.float32) for k in self.keys}
        feed["action_mask"] = np.asarray(action_mask, bool)
        if not batched:
            feed = {k: v[None] for k, v in feed.items()}
        try:
            logits, action = self.session.run(["masked_logits", "action"], feed)
        except Exception as exc:  # onnxruntime's errors have no common Python base.
            if type(exc).__module__.startswith("onnxruntime"):
                shapes = {k: list(v.shape) for k, v in feed.items()}
                raise UserInputError(
                    f"the observation does not fit the model ({str(exc).splitlines()[0]}): "
                    f"it takes {self.metadata.get('inputs')} per decision, it was given "
                    f"{shapes}.") from None
            raise
        return logits, action


def torch_actor_logits(policy: MaskableActorCriticPolicy, obs: dict[str, np.ndarray],
                       action_mask: np.ndarray) -> torch.Tensor:
    """The SB3 policy's own masked logits (B, A) for batched observation arrays: the
    reference the export is checked against."""
    with torch.no_grad():
        tensors = {k: torch.as_tensor(v) for k, v in obs.items()}
        logits = actor_logits(policy, tensors)
    return torch.where(torch.as_tensor(action_mask), logits, torch.tensor(MASKED_LOGIT))


def record_decisions(weights: str | os.PathLike, count: int, scene: str = "train_loop",
                     seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Observations and action masks of up to ``count`` decisions of one episode (kinematic
    dynamics) in which the policy in ``weights`` picks its greedy valid action.

    Returns:
        (observation arrays, each (D, ...), action masks (D, A)), D <= ``count``.
    """
    from mjexplore.envs import EnvConfig, ExplorationEnv
    from mjexplore.episode import EpisodeConfig
    from mjexplore.sim.simulator import SimConfig

    policy, meta = load_policy(weights)
    config = meta["decisions"].config
    layout = ({"observation": config} if meta["kind"] == "gvn"
              else {"decisions": "grid", "grid": config})
    env = ExplorationEnv(EnvConfig(scenes=(scene,), max_decisions=count, **layout,
                                   episode=EpisodeConfig(sim=SimConfig(dynamics="kinematic"))))
    observations, masks = [], []
    obs, info = env.reset(seed=seed)
    done = info["end_reason"] is not None
    while not done:
        mask = env.action_masks()
        observations.append(obs)
        masks.append(mask)
        action, _ = policy.predict(obs, deterministic=True, action_masks=mask)
        obs, _, terminated, truncated, info = env.step(int(action))
        done = terminated or truncated
    return ({k: np.stack([o[k] for o in observations]) for k in observations[0]},
            np.stack(masks))


__all__ = ["ExportedActor", "FORMAT", "MASKED_LOGIT", "OnnxActor", "export_onnx",
           "gvn_features", "gvn_v2_features", "record_decisions", "spatial_gather",
           "torch_actor_logits"]
