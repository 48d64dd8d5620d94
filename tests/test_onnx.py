"""ONNX export of the policies' actors: onnxruntime gives torch's logits and actions."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import torch

from mjexplore.errors import UserInputError
from mjexplore.policies.gvn import GvnConfig, SpatialEncoder
from mjexplore.policies.models import MODELS_DIR
from mjexplore.policies.onnx_export import (
    FORMAT,
    MASKED_LOGIT,
    OnnxActor,
    export_onnx,
    record_decisions,
    spatial_gather,
    torch_actor_logits,
)
from mjexplore.policies.weights import load_policy

WEIGHTS = {kind: MODELS_DIR / name / "policy.safetensors" for kind, name in
           (("gvn", "gvn_paper"), ("cnn", "cnn_paper"))}


def test_gathered_gcn_equals_the_sparse_one():
    rng = np.random.default_rng(0)
    m, n, k = 5, 12, 4
    mask = (rng.random((m, n)) < 0.6).astype(np.float32)  # Padding anywhere, not only last.
    mask[0] = 0.0  # A graph without nodes (an unfilled memory slot).
    neighbours = rng.integers(-1, n, (m, n, k)).astype(np.float32)  # Edges to padding too.
    neighbours[1, 0, :2] = 3.0  # A repeated neighbour counts twice, as in the sparse sum.
    features = rng.normal(0.0, 3.0, (m, n, 6)).astype(np.float32)
    torch.manual_seed(0)
    encoder = SpatialEncoder(GvnConfig(hidden=8))
    args = [torch.as_tensor(a) for a in (features, neighbours, mask)]
    with torch.no_grad():
        expected = encoder(*args)
        got = spatial_gather(encoder, *args)
    assert expected.abs().sum() > 0
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)


@pytest.mark.slow  # An export takes 5-15 s on 2 cores.
@pytest.mark.parametrize("kind", ["gvn", "cnn"])
def test_onnxruntime_gives_torchs_logits_and_actions(kind, tmp_path):
    weights = WEIGHTS[kind]
    path = tmp_path / f"{kind}.onnx"
    props = export_onnx(weights, path)
    # 13 decisions of an episode: the GVN's memory (10 decisions) fills and moves on.
    obs, masks = record_decisions(weights, 13, "train_office_small")
    assert len(masks) == 13
    if kind == "gvn":
        assert obs["memory_mask"][-1].all() and obs["memory_choice"][-1].any()

    actor = OnnxActor(path)
    assert actor.metadata["weights_sha256"] == hashlib.sha256(weights.read_bytes()).hexdigest()
    assert actor.metadata["format"] == FORMAT and actor.metadata["kind"] == kind
    assert actor.keys == json.loads(props["observation_keys"])
    assert sorted(actor.keys) == sorted(obs)
    inputs = json.loads(actor.metadata["inputs"])
    assert list(inputs) == [*actor.keys, "action_mask"]
    assert all(inputs[key]["shape"] == list(value.shape[1:]) for key, value in obs.items())
    assert inputs["action_mask"] == {"shape": [masks.shape[1]], "dtype": "bool"}

    policy, _ = load_policy(weights)
    expected = torch_actor_logits(policy, obs, masks).numpy()
    greedy = [int(policy.predict({k: v[i] for k, v in obs.items()}, deterministic=True,
                                 action_masks=masks[i])[0]) for i in range(len(masks))]
    logits, actions = actor(obs, masks)  # All decisions as one batch...
    np.testing.assert_allclose(logits, expected, atol=1e-4, rtol=0)
    assert (logits[~masks] == MASKED_LOGIT).all()
    assert actions.tolist() == greedy == expected.argmax(1).tolist()
    for i in (0, len(masks) - 1):  # ...and one at a time, as a robot would call it.
        one_logits, one_action = actor({k: v[i] for k, v in obs.items()}, masks[i])
        np.testing.assert_allclose(one_logits[0], expected[i], atol=1e-4, rtol=0)
        assert int(one_action[0]) == greedy[i]


def test_bad_files_are_refused_with_a_clear_error(tmp_path):
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(UserInputError, match="not a readable safetensors"):
        export_onnx(junk, tmp_path / "out.onnx")
    with pytest.raises(UserInputError, match="cannot read ONNX model"):
        OnnxActor(junk)
    assert not (tmp_path / "out.onnx").exists()
