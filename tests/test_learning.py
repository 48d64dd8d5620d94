"""The learning stack: env, GVN layers, masking, training with resume, shipped weights."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import random_tree
from gymnasium import spaces

from mjexplore.config import from_dict, to_dict
from mjexplore.envs import (
    ENV_IDS,
    EnvConfig,
    ExplorationEnv,
    ObservationConfig,
    RewardConfig,
    TerMemory,
)
from mjexplore.envs.observation import observation_space, structured
from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.errors import UserInputError
from mjexplore.learning.checkpoints import load_checkpoint
from mjexplore.learning.train_config import TrainConfig, load_train_config
from mjexplore.learning.training import make_model, train
from mjexplore.learning.vec_envs import make_vec_env
from mjexplore.navigation.navigator import NavigatorConfig
from mjexplore.policies.gvn import (
    CausalConv,
    GraphConv,
    GvnConfig,
    SpatialEncoder,
    TemporalEncoder,
    distinct_graphs,
    normalized_adjacency,
)
from mjexplore.policies.sb3 import GvnPolicy
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "models" / "gvn_paper" / "policy.safetensors"
FAST = EpisodeConfig(sim=SimConfig(dynamics="kinematic"),
                     navigator=NavigatorConfig(replan_rate_hz=0.5, replan_when_blocked=True))
SMALL = ObservationConfig(max_nodes=12, max_neighbours=3, memory_length=4)


def _random_obs(config: ObservationConfig, batch: int, rng: np.random.Generator):
    """Random but well-formed observations (symmetric neighbour lists)."""
    n, k, e = config.max_nodes, config.max_neighbours, config.memory_length

    def graph():
        real = int(rng.integers(3, n + 1))
        neigh = random_tree(rng, n, k, real)
        feats = np.zeros((n, 6), np.float32)
        feats[:real] = rng.normal(size=(real, 6))
        mask = np.zeros(n, np.float32)
        mask[:real] = 1
        return {"node_features": feats, "neighbours": neigh, "node_mask": mask}, real

    out = []
    for _ in range(batch):
        memory = TerMemory(config)
        for _ in range(int(rng.integers(0, e + 2))):
            g, real = graph()
            memory.remember(g, int(rng.integers(real)))
        g, _ = graph()
        out.append(memory.observation(g))
    return {key: torch.as_tensor(np.stack([o[key] for o in out])) for key in out[0]}


def _policy(masking: str = "iam", config: ObservationConfig = SMALL) -> GvnPolicy:
    torch.manual_seed(0)
    return GvnPolicy(observation_space(config), spaces.Discrete(config.max_nodes),
                     lambda _: 1e-3, masking=masking, hidden=16)


# ----------------------------------------------------------------------------- network


def test_gcn_layer_equals_dense_formula():
    rng = np.random.default_rng(0)
    n = 6
    edges = [(0, 1), (1, 2), (2, 3), (1, 4)]  # Node 5 is padding.
    neigh = np.full((1, n, 3), -1.0, np.float32)
    fill = np.zeros(n, int)
    for a, b in edges:
        neigh[0, a, fill[a]], neigh[0, b, fill[b]] = b, a
        fill[a] += 1
        fill[b] += 1
    mask = np.array([[1, 1, 1, 1, 1, 0]], np.float32)
    h = torch.as_tensor(rng.normal(size=(5, 4)), dtype=torch.float32)  # The real nodes.
    layer = GraphConv(4, 5)
    real_rows = torch.as_tensor(mask).reshape(-1).nonzero().squeeze(1)
    out = layer(h, normalized_adjacency(torch.as_tensor(neigh), real_rows))
    a = np.zeros((5, 5))
    for i, j in edges:
        a[i, j] = a[j, i] = 1
    a_hat = a + np.eye(5)
    d = np.diag(a_hat.sum(1) ** -0.5)
    w = layer.weight.weight.detach().numpy().T
    dense = d @ a_hat @ d @ h.numpy() @ w
    np.testing.assert_allclose(out.detach().numpy(), dense, rtol=1e-5, atol=1e-6)


def test_spatial_encoder_ignores_padding_and_batch_neighbours():
    """A graph's embeddings do not depend on how much padding or which other graphs share
    the batch (only real nodes are computed)."""
    torch.manual_seed(0)
    encoder = SpatialEncoder(GvnConfig(hidden=8))
    feats = torch.randn(1, 4, 6)
    neigh = torch.tensor([[[1, -1], [0, 2], [1, 3], [2, -1]]], dtype=torch.float32)
    alone = encoder(feats, neigh, torch.ones(1, 4))
    # The same graph padded to 7 slots, after an empty graph and before a different one.
    f = torch.zeros(3, 7, 6)
    n = torch.full((3, 7, 2), -1.0)
    m = torch.zeros(3, 7)
    f[1, :4], n[1, :4], m[1, :4] = feats[0], neigh[0], 1
    f[2, :2], n[2, 0, 0], n[2, 1, 0], m[2, :2] = torch.randn(2, 6), 1, 0, 1
    batched = encoder(f, n, m)
    assert torch.allclose(batched[1, :4], alone[0], atol=1e-6)
    assert torch.all(batched[0] == 0) and torch.all(batched[1, 4:] == 0)


def test_tcn_is_causal():
    torch.manual_seed(0)
    tcn = TemporalEncoder(GvnConfig(hidden=8))
    x = torch.randn(2, 10, 8)
    y = tcn(x)
    for t in range(9):
        x2 = x.clone()
        x2[:, t + 1:] = torch.randn_like(x2[:, t + 1:])
        y2 = tcn(x2)
        assert torch.allclose(y[:, :t + 1], y2[:, :t + 1], atol=1e-6)
        assert not torch.allclose(y[:, t + 1:], y2[:, t + 1:])
    conv = CausalConv(1, 3, 2)
    assert conv.pad == 4


@pytest.mark.parametrize("masking", ["iam", "naive"])
def test_masked_nodes_get_zero_probability_and_gradient(masking):
    policy = _policy(masking)
    obs = _random_obs(SMALL, 4, np.random.default_rng(1))
    coin = torch.rand(obs["node_mask"].shape, generator=torch.Generator().manual_seed(0))
    valid = obs["node_mask"].bool() & (coin < 0.5)
    valid[:, 0] = True
    features = policy.extract_features(obs)
    logits = policy.mlp_extractor.forward_actor(features)
    logits.retain_grad()
    dist = policy._get_action_dist_from_latent(logits)
    dist.apply_masking(valid)
    probs = dist.distribution.probs
    assert torch.all(probs[~valid] == 0)
    actions = dist.get_actions()
    assert torch.all(valid[torch.arange(4), actions])
    _, log_prob, _ = policy.evaluate_actions(obs, actions, valid)
    policy.zero_grad()
    logits_eval = None
    node_logits = policy.mlp_extractor.node_logits

    def kept(z):
        nonlocal logits_eval
        logits_eval = node_logits(z)
        logits_eval.retain_grad()
        return logits_eval

    policy.mlp_extractor.node_logits = kept
    _, log_prob, _ = policy.evaluate_actions(obs, actions, valid)
    del policy.mlp_extractor.node_logits
    log_prob.sum().backward()
    grad = logits_eval.grad
    invalid_real = obs["node_mask"].bool() & ~valid
    assert grad[valid].abs().max() > 1e-3
    if masking == "iam":
        # Zero analytically; sb3-contrib normalises the raw logits before masking, which
        # leaves float32 round-off (~1e-9) behind.
        assert grad[~valid].abs().max() < 1e-6
    else:  # Naive masking: gradients reach the logits of invalid (real) nodes.
        assert grad[invalid_real].abs().max() > 1e-3


def test_policy_forward_samples_valid_nodes_only():
    policy = _policy()
    obs = _random_obs(SMALL, 8, np.random.default_rng(2))
    valid = torch.zeros(8, SMALL.max_nodes, dtype=torch.bool)
    valid[:, 1] = True
    valid[:, 2] = True
    for _ in range(5):
        actions, values, log_prob = policy(obs, action_masks=valid)
        assert set(actions.tolist()) <= {1, 2}
        assert values.shape == (8, 1) and torch.isfinite(log_prob).all()


def test_memory_matters_and_padding_does_not():
    policy = _policy()
    rng = np.random.default_rng(3)
    obs = _random_obs(SMALL, 1, rng)
    base = policy.mlp_extractor.forward_actor(policy.extract_features(obs))
    other = dict(obs)
    other["memory_mask"] = torch.zeros_like(obs["memory_mask"])
    other["memory_node_features"] = torch.zeros_like(obs["memory_node_features"])
    assert obs["memory_mask"].sum() > 0  # This seed draws a non-empty memory.
    changed = policy.mlp_extractor.forward_actor(policy.extract_features(other))
    assert not torch.allclose(base, changed)
    # Garbage in padding slots of the current TER changes nothing on real nodes.
    noisy = dict(obs)
    feats = obs["node_features"].clone().view(1, SMALL.max_nodes, 6)
    feats[obs["node_mask"] == 0] = 99.0
    noisy["node_features"] = feats.view(1, -1)
    again = policy.mlp_extractor.forward_actor(policy.extract_features(noisy))
    real = obs["node_mask"] > 0
    assert torch.allclose(base[real], again[real], atol=1e-5)


def test_distinct_graphs_merges_equal_graphs_only():
    torch.manual_seed(0)
    feats = torch.randn(5, 12, 6)
    feats[:] = feats[0]
    neigh = torch.tensor([[1, -1], [0, 2], [1, -1]] + [[-1, -1]] * 9,
                         dtype=torch.float32).repeat(5, 1, 1)
    mask = torch.zeros(5, 12)
    mask[:, :10] = 1
    feats[2, 8, 1] += 1e-3  # Beyond the sorting key: only the full comparison tells.
    feats[4] = feats[2]
    neigh[3, 2, 1] = 0  # The same node features, one more edge.
    keep, inverse = distinct_graphs(feats, neigh, mask)
    assert keep.tolist() == [0, 2, 3] and inverse.tolist() == [0, 0, 1, 2, 1]


def _reference_features(policy: GvnPolicy, obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The GVN's features [z (N d), pooled (2 d)] by the dense formulas, one TER copy at a
    time (paper Eq. 8-12): the reference of the batched encoder, which encodes each distinct
    TER of a batch once, on its real nodes only."""
    gvn = policy.features_extractor.gvn
    enc = gvn.spatial
    s = structured(obs)

    def embed(feat, neigh, mask):  # (N, 6), (N, K), (N,) -> (N, d), zero on padding.
        n = len(mask)
        real = mask > 0
        slots = neigh.long()
        i, k = (slots >= 0).nonzero(as_tuple=True)
        j = slots[i, k]
        joins = real[j]  # An edge to a padding slot counts in the degree only.
        a_hat = torch.eye(n).index_put((i[joins], j[joins]), torch.ones(int(joins.sum())),
                                       accumulate=True)
        inv = (1.0 + (slots >= 0).sum(1)).rsqrt()
        a_norm = inv[:, None] * a_hat * inv[None, :]
        h = feat * enc.scale
        for layer_index, layer in enumerate(enc.layers):
            skip = enc.input_skip(h) if layer_index == 0 else h
            h = torch.relu(a_norm @ layer.weight(h)) + skip
        return h * real[:, None]

    out = []
    for b in range(len(s["node_mask"])):
        fragments = []
        for j in range(s["memory_mask"].shape[1]):
            m = s["memory_node_mask"][b, j]
            h = embed(s["memory_node_features"][b, j], s["memory_neighbours"][b, j], m)
            mean = h.sum(0) / m.sum().clamp(min=1.0)
            fragments.append(gvn.fragment(torch.cat([mean, h[int(s["memory_choice"][b, j])]])))
        memory = gvn.temporal(torch.stack(fragments)[None]
                              * s["memory_mask"][b, None, :, None])[0, -1]
        real = s["node_mask"][b] > 0
        r = embed(s["node_features"][b], s["neighbours"][b], s["node_mask"][b])
        hm = memory.expand_as(r)
        alpha = torch.softmax(torch.cat([gvn.attention(r), gvn.attention(hm)], -1), -1)
        z = gvn.aggregator(torch.cat([alpha[:, :1] * r + alpha[:, 1:] * hm, r], -1))
        z = z * real[:, None]
        out.append(torch.cat([z.flatten(), z[real].mean(0), z[real].amax(0)]))
    return torch.stack(out)


def test_batched_encoder_gives_the_ppo_loss_terms_of_the_per_ter_reference(monkeypatch):
    """On a shuffled minibatch of real training observations (each TER recurs in the
    memories of the next decisions), values, log-probabilities, entropy and their gradients
    are those of encoding every TER copy on its own with the dense formulas."""
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, max_decisions=8))
    rng = np.random.default_rng(0)
    steps = []
    obs, _ = env.reset(seed=0)
    while len(steps) < 14:
        mask = env.action_masks()
        action = int(rng.choice(np.flatnonzero(mask)))
        steps.append((obs, mask, action))
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset(seed=len(steps))
    order = rng.permutation(len(steps))
    batch = {k: torch.as_tensor(np.stack([steps[i][0][k] for i in order])) for k in obs}
    masks = torch.as_tensor(np.stack([steps[i][1] for i in order]))
    actions = torch.as_tensor([steps[i][2] for i in order])
    s = structured(batch)
    stacked = [torch.cat([s[key][:, None], s[f"memory_{key}"]], 1).flatten(0, 1)
               for key in ("node_features", "neighbours", "node_mask")]
    _, inverse = distinct_graphs(*stacked)
    real = stacked[2].sum(-1) > 0
    assert len(set(inverse[real].tolist())) < real.sum() / 3  # Copies to share.

    torch.manual_seed(0)
    policy = GvnPolicy(env.observation_space, env.action_space, lambda _: 1e-3, hidden=16)

    def loss_terms():
        policy.zero_grad()
        values, log_prob, entropy = policy.evaluate_actions(batch, actions, masks)
        (values.sum() + log_prob.sum() + entropy.sum()).backward()
        grads = {n: p.grad.clone() for n, p in policy.named_parameters() if p.grad is not None}
        return (values, log_prob, entropy), grads

    batched, batched_grads = loss_terms()
    monkeypatch.setattr(policy.features_extractor, "forward",
                        lambda o: _reference_features(policy, o))
    reference, reference_grads = loss_terms()
    for a, b in zip(batched, reference):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert batched_grads.keys() == reference_grads.keys()
    scale = max(float(g.norm()) for g in reference_grads.values())
    for name, g in reference_grads.items():
        assert float((batched_grads[name] - g).norm()) <= 1e-5 * scale, name


# ----------------------------------------------------------------------------- env


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_for_every_registered_id(env_id, tmp_path):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    overrides = {"max_decisions": 4}
    env = gym.make(env_id, **overrides).unwrapped
    if env.config.procedural is not None:
        env = ExplorationEnv(dataclasses.replace(env.config, procedural=dataclasses.replace(
            env.config.procedural, cache_dir=str(tmp_path))), max_decisions=4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check(env, skip_render_check=True)
        sb3_check(env, warn=True)
    assert not caught, [str(w.message) for w in caught]


def test_env_is_deterministic_and_reports_reward_terms():
    config = EnvConfig(scenes=("train_loop",), episode=FAST, max_decisions=6,
                       reward=RewardConfig(kind="paper"))

    from mjexplore.mapping.metrics import accuracy

    def rollout():
        env = ExplorationEnv(config)
        obs, _ = env.reset(seed=3)
        ep = env.episode
        start, cell_area = accuracy(ep.mapper.grid, ep.reference), ep.mapper.grid.resolution ** 2
        out = [obs["node_features"].copy()]
        rewards, infos = [], []
        for _ in range(6):
            mask = env.action_masks()
            assert mask.any() and np.all(obs["node_mask"][mask] == 1)
            obs, r, term, trunc, info = env.step(int(np.flatnonzero(mask)[-1]))
            rewards.append(r)
            infos.append(info)
            # r_Acc: Eq. 18's accuracy (mapping.metrics.accuracy) gained over the steps.
            assert sum(i["accuracy_m2"] for i in infos) == pytest.approx(
                (accuracy(ep.mapper.grid, ep.reference) - start) * cell_area)
            if term or trunc:
                break
        return out, rewards, infos

    a, ra, ia = rollout()
    b, rb, _ = rollout()
    np.testing.assert_array_equal(a[0], b[0])
    assert ra == rb
    info = ia[0]
    cfg = config.reward
    expected = cfg.scale * (cfg.b1 * info["gain_m2"] - cfg.b2 * info["path_m"] +
                            cfg.b3 * info["accuracy_m2"] - cfg.b4)
    assert ra[0] == pytest.approx(expected)
    assert info["gain_m2"] > 0 and info["path_m"] > 0
    # Six decisions end the episode unless exploring did first.
    assert ia[-1]["end_reason"] in ("decision_limit", "explored", "no_frontiers")
    assert len(ra) == 6 or ia[-1]["end_reason"] != "decision_limit"


def test_an_episode_cut_short_returns_the_state_it_ended_in():
    import dataclasses

    env = ExplorationEnv(EnvConfig(scenes=("train_loop",),
                                   episode=dataclasses.replace(FAST, max_time=8.0)))
    obs, _ = env.reset(seed=0)
    before = obs
    terminated = truncated = False
    while not (terminated or truncated):
        before = obs
        obs, _, terminated, truncated, info = env.step(int(np.flatnonzero(env.action_masks())[0]))
    assert truncated and info["end_reason"] == "time_limit"
    env.decisions.prepare(env.episode.decision_state())  # The state the episode ended in.
    fresh = env.decisions.observation()
    for key in ("node_features", "node_mask", "neighbours"):
        np.testing.assert_array_equal(obs[key], fresh[key])
    assert not np.array_equal(obs["node_features"], before["node_features"])


def test_the_last_allowed_decision_is_driven_before_the_limit_ends_the_episode():
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, max_decisions=2))
    env.reset(seed=0)
    for _ in range(2):
        t0 = env.episode.sim.time
        _, _, terminated, truncated, info = env.step(int(np.flatnonzero(env.action_masks())[0]))
        assert info["sim_time"] > t0 and info["path_m"] > 0
    assert truncated and not terminated and info["end_reason"] == "decision_limit"
    assert info["episode_metrics"]["decisions"] == 2


def test_invalid_action_is_a_no_op_with_the_step_cost():
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST,
                                   reward=RewardConfig(kind="paper")))
    obs, info = env.reset(seed=0)
    padding = int(np.flatnonzero(obs["node_mask"] == 0)[0])
    t0 = info["sim_time"]
    _, reward, term, trunc, info = env.step(padding)
    assert info["invalid_action"] and info["sim_time"] == t0
    assert reward == pytest.approx(-env.config.reward.scale * env.config.reward.b4)
    assert not (term or trunc)


def test_memory_in_observation_follows_decisions():
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST))
    obs, _ = env.reset(seed=1)
    assert obs["memory_mask"].sum() == 0
    first = obs["node_features"].copy()
    action = int(np.flatnonzero(env.action_masks())[0])
    obs, *_ = env.step(action)
    assert obs["memory_mask"].tolist() == [0.0] * 9 + [1.0]
    np.testing.assert_array_equal(obs["memory_node_features"][-len(first):], first)
    assert obs["memory_choice"][-1] == action


# ----------------------------------------------------------------------------- configs


def test_train_config_round_trip_and_errors(tmp_path):
    config = load_train_config(REPO / "training" / "gvn.yaml")
    assert from_dict(TrainConfig, to_dict(config)) == config
    bad = {"ppo": {"n_stepz": 3}}
    with pytest.raises(UserInputError, match="unknown key"):
        from_dict(TrainConfig, bad)
    with pytest.raises(UserInputError, match="expected a number"):
        from_dict(TrainConfig, {"ppo": {"gamma": "high"}})
    with pytest.raises(UserInputError, match="gamma"):
        from_dict(TrainConfig, {"ppo": {"gamma": 1.5}})
    with pytest.raises(UserInputError, match="masking"):
        from_dict(TrainConfig, {"policy": {"masking": "sometimes"}})
    for policy, env in (({"masking": "none"}, {}), ({}, {"valid_actions": "all_nodes"})):
        with pytest.raises(UserInputError, match="all_nodes"):
            from_dict(TrainConfig, {"policy": policy, "env": {"scenes": ["train_loop"], **env}})
    path = tmp_path / "broken.yaml"
    path.write_text("ppo: [unclosed\n")
    with pytest.raises(UserInputError, match="not valid YAML"):
        load_train_config(path)


def test_every_shipped_recipe_loads():
    from mjexplore.learning.pocket_training import PocketTrainingConfig, load_pocket_config
    from mjexplore.learning.predictor_training import (
        PredictorTrainingConfig,
        load_predictor_config,
    )

    loaders = {"pockets.yaml": (load_pocket_config, PocketTrainingConfig),
               "predictor.yaml": (load_predictor_config, PredictorTrainingConfig)}
    recipes = sorted((REPO / "training").glob("*.yaml"))
    assert len(recipes) >= 21
    for path in recipes:
        load, kind = loaders.get(path.name, (load_train_config, TrainConfig))
        assert isinstance(load(path), kind), path.name


def test_a_recipe_extends_another_key_by_key(tmp_path):
    (tmp_path / "base.yaml").write_text(
        "total_steps: 5000\nppo: {n_steps: 64, learning_rate: 0.001}\n"
        "imitation: {episodes: 4}\n")
    (tmp_path / "child.yaml").write_text(
        "extends: base.yaml\nppo: {n_steps: 32}\nimitation: null\n")
    base = load_train_config(tmp_path / "base.yaml")
    child = load_train_config(tmp_path / "child.yaml")
    assert (child.total_steps, child.ppo.learning_rate) == (5000, 0.001)  # Inherited.
    assert (base.ppo.n_steps, child.ppo.n_steps) == (64, 32)  # Merged into ppo.
    assert base.imitation.episodes == 4
    assert child.imitation == TrainConfig().imitation  # null: the defaults again.
    nested = tmp_path / "sub"
    nested.mkdir()
    (nested / "grandchild.yaml").write_text("extends: ../child.yaml\nseed: 3\n")
    grandchild = load_train_config(nested / "grandchild.yaml")
    assert grandchild == dataclasses.replace(child, seed=3)

    (tmp_path / "loop_a.yaml").write_text("extends: loop_b.yaml\n")
    (tmp_path / "loop_b.yaml").write_text("extends: loop_a.yaml\n")
    with pytest.raises(UserInputError, match="leads back"):
        load_train_config(tmp_path / "loop_a.yaml")
    (tmp_path / "missing.yaml").write_text("extends: nowhere.yaml\n")
    with pytest.raises(UserInputError, match="cannot read config .*nowhere.yaml"):
        load_train_config(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("extends: [base.yaml]\n")
    with pytest.raises(UserInputError, match="extends must name"):
        load_train_config(tmp_path / "bad.yaml")


def test_an_error_in_a_merged_recipe_names_the_file_that_set_the_key(tmp_path):
    (tmp_path / "base.yaml").write_text("ppo: {learning_rate: fast, n_stepz: 3}\n")
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nseed: 3\n")
    (tmp_path / "grandchild.yaml").write_text("extends: child.yaml\nppo: {n_steps: 32}\n")
    with pytest.raises(UserInputError, match=r"grandchild.yaml.ppo: unknown key\(s\) n_stepz.*"
                       r"merges grandchild.yaml -> child.yaml -> base.yaml; set in: base.yaml\)"):
        load_train_config(tmp_path / "grandchild.yaml")
    (tmp_path / "base.yaml").write_text("ppo: {learning_rate: fast}\n")
    with pytest.raises(UserInputError, match=r"ppo.learning_rate: expected a number.*"
                       r"set in: base.yaml\)"):
        load_train_config(tmp_path / "grandchild.yaml")
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nppo: {learning_rate: slow}\n")
    with pytest.raises(UserInputError, match=r"set in: child.yaml, base.yaml\)"):
        load_train_config(tmp_path / "grandchild.yaml")


@pytest.mark.parametrize("recipe,budget", [("gvn", 27648), ("gvn_v2", 8704)])
def test_ablation_configs_differ_from_the_shipped_one_only_in_masking(recipe, budget):
    import dataclasses

    from mjexplore.policies.weights import read_policy_weights

    shipped = load_train_config(REPO / "training" / f"{recipe}.yaml")
    # The budget: the decisions the shipped policy was trained for (its weights are the
    # best held-out checkpoint up to there).
    _, meta = read_policy_weights(REPO / "models" / {"gvn": "gvn_paper"}.get(recipe, recipe)
                                   / "policy.safetensors")
    assert meta["provenance"]["num_timesteps"] <= budget
    for name, masking, valid in ((f"{recipe}_naive", "naive", "frontiers"),
                                 (f"{recipe}_none", "none", "all_nodes")):
        config = load_train_config(REPO / "training" / f"{name}.yaml")
        assert (config.policy.masking, config.env.valid_actions) == (masking, valid)
        assert config.total_steps == budget
        same = dataclasses.replace(
            config, total_steps=shipped.total_steps,
            policy=dataclasses.replace(config.policy, masking="iam"),
            env=dataclasses.replace(config.env, valid_actions="frontiers"))
        assert same == shipped


# ----------------------------------------------------------------------------- training

TINY = """
kind: gvn
total_steps: {total}
n_envs: {n_envs}
checkpoint_every: 8
env:
  scenes: [train_loop]
  max_decisions: 12
  observation: {{max_nodes: 64, max_neighbours: 4, memory_length: 3}}
  episode:
    sim: {{dynamics: kinematic}}
    navigator: {{replan_rate_hz: 0.5, replan_when_blocked: true}}
policy: {{hidden: 16}}
ppo: {{n_steps: 8, batch_size: 8, n_epochs: 1}}
eval: {{every: 0}}
"""


def _train_cli(args, **kw):
    return subprocess.run([sys.executable, "-m", "mjexplore.cli", "train", "--no-progress",
                           *args], capture_output=True, text=True, **kw)


def test_training_with_minibatch_runs_update_threads_and_a_privileged_critic(tmp_path,
                                                                              monkeypatch):
    from mjexplore.learning import rollout_blocks
    from mjexplore.learning.training import train
    from mjexplore.policies.weights import load_policy

    threads_in_updates = []
    get = rollout_blocks.BlockDictRolloutBuffer.get

    def counted_get(self, batch_size=None):
        threads_in_updates.append(torch.get_num_threads())
        return get(self, batch_size)

    monkeypatch.setattr(rollout_blocks.BlockDictRolloutBuffer, "get", counted_get)
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=16, n_envs=1).replace(
        "n_epochs: 1}", "n_epochs: 2, minibatch_block: 4}").replace(
        "memory_length: 3}", "memory_length: 3, features: v2, privileged: true}")
        + "update_threads: 2\n")
    config = load_train_config(cfg)
    assert (config.ppo.minibatch_block, config.update_threads) == (4, 2)
    assert config.env.observation.privileged
    result = train(config, tmp_path / "run", progress=False)
    assert result["num_timesteps"] == 16
    assert threads_in_updates == [2] * 4  # Two updates of two epochs.
    assert torch.get_num_threads() == config.torch_threads
    policy, meta = load_policy(result["weights"], expected_kind="gvn")
    assert meta["decisions"].config.privileged
    assert policy.mlp_extractor.critic[0].in_features == 2 * 16 + 2


def test_train_flags_replace_the_configs_steps_and_envs(tmp_path, capsys):
    from mjexplore.cli import main

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=64, n_envs=2))
    for flag, value in (("--total-steps", "0"), ("--n-envs", "two"), ("--n-envs", "-1")):
        with pytest.raises(SystemExit) as exc:
            main(["train", "--config", str(cfg), "--out", str(tmp_path / "bad"), flag, value])
        assert exc.value.code == 2 and f"argument {flag}" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    config = load_train_config(cfg, total_steps=8, n_envs=1)
    assert (config.total_steps, config.n_envs) == (8, 1)
    assert config == dataclasses.replace(load_train_config(cfg), total_steps=8, n_envs=1)
    out = tmp_path / "run"
    r = _train_cli(["--config", str(cfg), "--out", str(out), "--total-steps", "8",
                    "--n-envs", "1"])
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[-1])["num_timesteps"] == 8
    saved = load_train_config(out / "config.yaml")
    assert (saved.total_steps, saved.n_envs) == (8, 1)
    # Another training seed of the same recipe: the run's seed changes, the validation
    # layouts' does not, and a resume cannot switch seeds.
    assert load_train_config(cfg, seed=3) == dataclasses.replace(load_train_config(cfg), seed=3)
    r = _train_cli(["--config", str(cfg), "--out", str(tmp_path / "seed3"), "--total-steps",
                    "8", "--n-envs", "1", "--seed", "3"])
    assert r.returncode == 0, r.stderr
    saved = load_train_config(tmp_path / "seed3" / "config.yaml")
    assert saved.seed == 3 and saved.eval.seed == load_train_config(cfg).eval.seed
    r = _train_cli(["--config", str(cfg), "--out", str(tmp_path / "seed3"), "--total-steps",
                    "16", "--n-envs", "1", "--seed", "4", "--resume"])
    assert r.returncode == 2 and "seed" in r.stderr


@pytest.mark.slow
def test_training_saves_resumes_and_loads(tmp_path):
    from mjexplore.policies.weights import load_policy

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=16, n_envs=1))
    out = tmp_path / "run"
    r = _train_cli(["--config", str(cfg), "--out", str(out)])
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[-1])["num_timesteps"] == 16
    again = _train_cli(["--config", str(cfg), "--out", str(out)])
    assert again.returncode == 2 and "--resume" in again.stderr
    assert len(list((out / "checkpoints").glob("step_*.pt"))) == 2  # 8 and 16.
    # Steps, envs, the checkpoints kept and overlapping updates may change.
    cfg.write_text(TINY.format(total=32, n_envs=2).replace(
        "checkpoint_every: 8", "checkpoint_every: 8\nkeep_checkpoints: 2").replace(
        "n_epochs: 1}", "n_epochs: 1, overlap: true}"))
    r = _train_cli(["--config", str(cfg), "--out", str(out), "--resume"])
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout.splitlines()[-1])
    assert summary["resumed_from"] == 16 and summary["num_timesteps"] == 32
    assert sorted(p.name for p in (out / "checkpoints").glob("step_*.pt")) == [
        "step_000000016.pt", "step_000000032.pt"]
    cfg.write_text(TINY.format(total=48, n_envs=2).replace("n_epochs: 1}", "n_epochs: 2}"))
    refused = _train_cli(["--config", str(cfg), "--out", str(out), "--resume"])
    assert refused.returncode == 2 and "ppo.overlap may change" in refused.stderr
    state = load_checkpoint(out / "checkpoints" / "step_000000032.pt")
    assert state["num_timesteps"] == 32 and "git_revision" in state
    assert from_dict(TrainConfig, json.loads(state["config"])).total_steps == 32
    policy, meta = load_policy(out / "policy.safetensors", expected_kind="gvn")
    assert meta["layout"]["max_nodes"] == 64
    assert meta["provenance"]["num_timesteps"] == 32
    assert (out / "tb").is_dir() and (out / "config.yaml").is_file()
    first, second = json.loads((out / "sessions.json").read_text())["sessions"]
    assert (first["steps_from"], first["steps_to"], second["steps_from"],
            second["steps_to"]) == (0, 16, 16, 32)
    assert second["n_envs"] == 2 and second["cores"] >= 1 and second["device"] == "cpu"
    assert second["wall_s"] > 0 and second["learner_cpu_s"] > 0


@pytest.mark.slow
def test_train_refuses_other_files_and_clears_a_start_that_made_no_checkpoint(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=8, n_envs=1))
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = _train_cli(["--config", str(cfg), "--out", str(out)])
    assert r.returncode == 2 and "notes.txt" in r.stderr, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    (out / "notes.txt").unlink()
    # What a start interrupted before its first checkpoint leaves: its events would mix
    # with the next run's in TensorBoard.
    stale = out / "tb" / "ppo_0" / "events.out.tfevents.1.abandoned"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"old")
    (out / "config.yaml").write_text("# an earlier start\n")
    r = _train_cli(["--config", str(cfg), "--out", str(out)])
    assert r.returncode == 0, r.stderr
    assert not stale.exists() and [p.name for p in (out / "tb").iterdir()] == ["ppo_0"]
    assert "earlier start" in r.stderr


def test_training_starts_from_init_weights_and_refuses_another_network(tmp_path):
    from mjexplore.learning.policy_network import fresh_policy, network_kwargs
    from mjexplore.learning.training import train
    from mjexplore.policies.registry import layout_of
    from mjexplore.policies.weights import (
        load_policy,
        read_policy_weights,
        save_policy_weights,
        tensors_sha256,
    )

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=8, n_envs=1))
    config = load_train_config(cfg)
    policy = fresh_policy(config)
    with torch.no_grad():
        policy.value_net.bias.fill_(7.0)  # One PPO update moves it by about 1e-3.
    init = tmp_path / "init.safetensors"
    save_policy_weights(init, policy, config.kind, network_kwargs(config),
                        layout_of(config.kind, config.env), {"num_timesteps": 0, "note": "x"})
    train(config, tmp_path / "run", progress=False, init_weights=init)
    trained, _ = load_policy(tmp_path / "run" / "policy.safetensors")
    assert trained.value_net.bias.item() == pytest.approx(7.0, abs=0.05)
    record = json.loads((tmp_path / "run" / "init.json").read_text())
    assert record["tensors_sha256"] == tensors_sha256(read_policy_weights(init)[0])
    assert record["provenance"]["note"] == "x"
    assert not (tmp_path / "run" / "imitation.json").exists()
    other = tmp_path / "other.yaml"
    other.write_text(TINY.format(total=8, n_envs=1).replace("hidden: 16", "hidden: 8"))
    r = _train_cli(["--config", str(other), "--out", str(tmp_path / "run2"),
                    "--init-weights", str(init)])
    assert r.returncode == 2 and "another network" in r.stderr
    r = _train_cli(["--config", str(cfg), "--out", str(tmp_path / "run"), "--resume",
                    "--init-weights", str(init)])
    assert r.returncode == 2 and "fresh run" in r.stderr


@pytest.mark.slow
def test_resumed_training_keeps_the_best_weights_of_the_first_part(tmp_path, monkeypatch):
    import mjexplore.learning.evaluation as evaluation
    from mjexplore.policies.weights import read_policy_weights

    # Evaluations at 8 steps, at 16 (due as the first part ended: done at once on resume),
    # then at 24: at the same counts however the run was cut.
    ratios = iter([0.95, 0.90, 0.85])

    def fake_eval(policy, config, workers=1):
        return [{"scene": "train_loop", "exploration_time_s": 100.0, "path_length_m": 50.0,
                 "exploration_ratio": next(ratios), "end_reason": "explored"}]

    monkeypatch.setattr(evaluation, "evaluate_policy_episodes", fake_eval)
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=16, n_envs=1).replace("every: 0", "every: 8"))
    out = tmp_path / "run"
    train(load_train_config(cfg), out, progress=False)
    cfg.write_text(TINY.format(total=32, n_envs=1).replace("every: 0", "every: 8"))
    train(load_train_config(cfg), out, resume=True, progress=False)
    best = read_policy_weights(out / "best.safetensors")[1]["provenance"]
    assert best["eval"][0]["exploration_ratio"] == 0.95 and best["num_timesteps"] == 8
    assert [int(line.split(",")[0]) for line in
            (out / "eval.csv").read_text().splitlines()[1:]] == [8, 16, 24]


@pytest.mark.slow
def test_training_killed_with_sigkill_resumes_from_last_checkpoint(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY.format(total=400, n_envs=2))
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "mjexplore.cli", "train", "--no-progress",
                             "--config", str(cfg), "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    latest = out / "checkpoints" / "latest.json"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if latest.is_file() and json.loads(latest.read_text())["num_timesteps"] >= 32:
            break
        time.sleep(0.5)
    assert proc.poll() is None, "training ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    saved = json.loads(latest.read_text())["num_timesteps"]
    assert not list((out / "checkpoints").glob("*.tmp*"))
    cfg.write_text(TINY.format(total=saved + 16, n_envs=2))
    r = _train_cli(["--config", str(cfg), "--out", str(out), "--resume"])
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout.splitlines()[-1])
    assert summary["resumed_from"] == saved
    assert summary["num_timesteps"] >= saved + 16


# ----------------------------------------------------------------------------- weights


def test_damaged_weights_are_refused(tmp_path):
    from mjexplore.policies.weights import load_policy, save_policy_weights

    policy = _policy()
    path = tmp_path / "p.safetensors"
    save_policy_weights(path, policy, "gvn", {"masking": "iam", "hidden": 16},
                        dataclasses.asdict(SMALL))
    loaded, _ = load_policy(path)
    obs = _random_obs(SMALL, 2, np.random.default_rng(4))
    with torch.no_grad():
        assert torch.allclose(policy.predict_values(obs), loaded.predict_values(obs))
    (tmp_path / "cut.safetensors").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(UserInputError, match="not a readable safetensors"):
        load_policy(tmp_path / "cut.safetensors")
    (tmp_path / "x.pt").write_bytes(b"\x80\x04not a weights file")
    with pytest.raises(UserInputError):
        load_policy(tmp_path / "x.pt")
    with pytest.raises(UserInputError, match="cannot read"):
        load_policy(tmp_path / "missing.safetensors")


@pytest.mark.skipif(not SHIPPED.is_file(), reason="no shipped GVN weights in training/")
def test_shipped_policy_selects_only_valid_nodes_and_caches_memory_exactly():
    from mjexplore.envs.decisions import ter_action_mask
    from mjexplore.policies.gvn_explorer import GvnExplorer

    explorer = GvnExplorer("gvn_paper")
    chosen = []
    original = explorer.select_goal

    def checked(state):
        ter, _, _ = state.extras["tracker"].ter(state.grid, state.pose)
        padded = ter.padded(explorer.ter_config)
        valid = ter_action_mask(padded, state, "frontiers")
        goal = original(state)
        if not valid.any():  # No frontier node: the nearest frontier, or nothing left.
            assert goal is None or any(np.allclose(goal, f.goal) for f in state.frontiers)
            return goal
        idx = int(np.flatnonzero(np.all(padded.node_positions == goal.astype(np.float32),
                                        axis=1))[0])
        assert valid[idx]
        chosen.append(idx)
        return goal

    explorer.select_goal = checked
    episode = Episode(resolve_scene("train_loop"), explorer, 0,
                      dataclasses.replace(FAST, max_time=120.0))
    episode.run()
    assert len(chosen) >= 3
    # Cached fragments give the logits the full policy computes from the raw memory.
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST,
                                   observation=ObservationConfig(
                                       max_nodes=explorer.ter_config.max_nodes)))
    obs, _ = env.reset(seed=2)
    explorer.reset(np.random.default_rng(0))
    for _ in range(3):
        mask = env.action_masks()
        t = {k: torch.as_tensor(v)[None] for k, v in obs.items()}
        with torch.no_grad():
            full = explorer.policy.mlp_extractor.forward_actor(
                explorer.policy.extract_features(t))[0]
        current = {k: v for k, v in structured(obs, batch_dims=0).items()
                   if not k.startswith("memory")}
        cached, r = explorer.logits(current)
        real = obs["node_mask"] > 0
        assert torch.allclose(full[real], cached[real], atol=1e-4)
        action = int(np.flatnonzero(mask)[int(torch.argmax(cached[torch.as_tensor(mask)]))])
        with torch.no_grad():
            n = r.shape[1]
            frag = explorer.gvn.fragments(r[0], torch.arange(n),
                                          torch.as_tensor(current["node_mask"][:n])[None],
                                          torch.tensor([action]))
        explorer._fragments = torch.cat([explorer._fragments[:, 1:], frag[:, None]], 1)
        explorer._memory_mask = torch.cat([explorer._memory_mask[:, 1:], torch.ones(1, 1)], 1)
        obs, _, term, trunc, _ = env.step(action)
        if term or trunc:
            break


def test_cli_refuses_bad_policy_weights(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"garbage")
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "explore", "--scene", "train_loop",
                        "--explorer", "gvn", "--policy", str(bad), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "safetensors" in r.stderr
    assert not out.exists()
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "explore", "--scene", "train_loop",
                        "--explorer", "nearest", "--policy", str(bad), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "learned explorers" in r.stderr


def test_an_unknown_policy_is_refused_with_the_models_of_its_kind(tmp_path):
    from mjexplore.eval.methods import make_explorer

    for method, listed, other in (("gvn", "gvn_v3", "cnn_paper"), ("cnn", "cnn_v2", "gvn_v3")):
        with pytest.raises(UserInputError, match=listed) as info:
            make_explorer(method, policy=str(tmp_path / "missing.safetensors"))
        assert other not in str(info.value)  # Only the models the explorer can run.


def test_env_without_a_valid_action_goes_on_with_the_engines_fallback(monkeypatch):
    # As if the TER never offered a valid frontier node: the env must not end the episode
    # as no_frontiers while one can be reached; the engine's fallback explores instead.
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, observation=SMALL))
    monkeypatch.setattr(env.decisions, "prepare", lambda state: False)
    env.reset(seed=0)
    ep = env.episode
    assert ep.end_reason == "explored"
    assert ep.result().metrics["fallbacks"] > 0


def test_model_selection_scores_coverage_up_to_the_target_then_speed():
    from mjexplore.learning.evaluation import eval_score

    def runs(*rows):
        return [{"end_reason": end, "exploration_ratio": ratio, "exploration_time_s": t}
                for end, ratio, t in rows]

    faster = runs(("explored", 0.9855, 300.0), ("explored", 0.986, 400.0))
    overshooting = runs(("explored", 0.992, 301.0), ("explored", 0.995, 401.0))
    short = runs(("explored", 0.99, 100.0), ("time_limit", 0.97, 1800.0))
    assert eval_score(faster) > eval_score(overshooting) > eval_score(short)


def test_a_run_anchored_to_its_prior_trains_with_the_kl_in_the_entropys_place(tmp_path):
    from mjexplore.policies.weights import read_policy_weights

    cfg = tmp_path / "anchored.yaml"
    cfg.write_text(TINY.format(total=16, n_envs=1).replace(
        "memory_length: 3}", "memory_length: 3, features: v2}").replace(
        "{hidden: 16}", "{hidden: 16, prior_temperature: 1.0}").replace(
        "n_epochs: 1}", "n_epochs: 2, ent_coef: 0.0, prior_kl: 0.05, target_kl: 0.02, "
        "learning_rate: 0.01}"))
    config = load_train_config(cfg)
    venv = make_vec_env(config, seed=0)
    try:
        model = make_model(config, venv, seed=0)
        assert model.ent_coef == 0.05 and model.target_kl == 0.02
        assert model.policy.entropy_reference == "prior"
        model.learn(config.total_steps)
        # SB3 logs -(mean "entropy"): here the mean KL from the prior, >= 0 and moved.
        assert model.logger.name_to_value["train/entropy_loss"] > 0.0
    finally:
        venv.close()
    train(config, tmp_path / "run", progress=False)
    _, meta = read_policy_weights(tmp_path / "run" / "policy.safetensors")
    assert "entropy_reference" not in meta["policy_kwargs"]  # The update's setting only.
