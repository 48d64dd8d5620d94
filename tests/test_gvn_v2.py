"""Issue 17, learning stack: the time reward, the v2 observation and network, the logit
layer's initial gain, held-out model selection, and the shipped v1 weights unchanged."""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import random_tree
from gymnasium import spaces

from mjexplore.envs import EnvConfig, ExplorationEnv, ObservationConfig, RewardConfig, TerMemory
from mjexplore.envs.exploration import (
    HELDOUT_SEED_BASE,
    TEST_SEED_BASE,
    ProceduralScenes,
    heldout_scenes,
)
from mjexplore.envs.observation import (
    BLACKLISTED,
    PATH,
    UNREACHABLE,
    observation_space,
    poses_in_frame,
)
from mjexplore.episode import EpisodeConfig
from mjexplore.navigation.navigator import NavigatorConfig
from mjexplore.policies.gvn import EncodedTers, memory_pose_features
from mjexplore.policies.sb3 import GvnPolicy
from mjexplore.sim.simulator import SimConfig

REPO = Path(__file__).resolve().parents[1]
FAST = EpisodeConfig(sim=SimConfig(dynamics="kinematic"),
                     navigator=NavigatorConfig(replan_rate_hz=0.5, replan_when_blocked=True))
V2 = ObservationConfig(features="v2")
SMALL_V2 = ObservationConfig(max_nodes=12, max_neighbours=3, memory_length=4, features="v2")


def _random_obs(config: ObservationConfig, batch: int, rng: np.random.Generator,
                valid: bool = False):
    """Random well-formed observations (symmetric neighbour lists, node positions in the
    first two features); with ``valid`` also a mask of random frontier-like nodes."""
    n, k, e, f = (config.max_nodes, config.max_neighbours, config.memory_length,
                  config.num_features)

    def graph():
        real = int(rng.integers(3, n + 1))
        neigh = random_tree(rng, n, k, real)
        feats = np.zeros((n, f), np.float32)
        feats[:real] = rng.normal(size=(real, f)) * 3.0
        mask = np.zeros(n, np.float32)
        mask[:real] = 1
        return {"node_features": feats, "neighbours": neigh, "node_mask": mask}, real

    out, masks = [], []
    for _ in range(batch):
        memory = TerMemory(config)
        for _ in range(int(rng.integers(0, e + 2))):
            g, real = graph()
            memory.remember(g, int(rng.integers(real)), rng.normal(size=3))
        g, real = graph()
        out.append(memory.observation(g, rng.normal(size=3)))
        m = np.zeros(n, bool)
        m[rng.choice(real, size=max(1, real // 2), replace=False)] = True
        masks.append(m)
    obs = {key: torch.as_tensor(np.stack([o[key] for o in out])) for key in out[0]}
    return (obs, torch.as_tensor(np.stack(masks))) if valid else obs


def _policy(config: ObservationConfig, **kw) -> GvnPolicy:
    torch.manual_seed(0)
    return GvnPolicy(observation_space(config), spaces.Discrete(config.max_nodes),
                     lambda _: 1e-3, hidden=16, **kw)


# ----------------------------------------------------------------------------- reward


def _episode(config: EnvConfig, pick) -> tuple[float, float, list[dict]]:
    """(return, exploration time, infos) of one episode choosing ``pick(obs, mask)``."""
    env = ExplorationEnv(config)
    obs, info = env.reset(seed=0)
    start, total, infos = info["sim_time"], 0.0, []
    while True:
        obs, r, term, trunc, info = env.step(pick(obs, env.action_masks()))
        total += r
        infos.append(info)
        if term or trunc:
            assert sum(i["dt_s"] for i in infos) == pytest.approx(info["sim_time"] - start)
            return total, info["sim_time"], infos


def test_time_reward_pays_the_faster_episode_more():
    config = EnvConfig(scenes=("train_loop",), episode=FAST, observation=V2)

    def nearest(obs, mask):  # Least path cost, as nearest-frontier.
        path = obs["node_features"].reshape(V2.max_nodes, -1)[:, PATH]
        return int(np.flatnonzero(mask)[np.argmin(path[mask])])

    def farthest(obs, mask):  # Most path cost: back and forth across the map.
        path = obs["node_features"].reshape(V2.max_nodes, -1)[:, PATH]
        return int(np.flatnonzero(mask)[np.argmax(path[mask])])

    fast, fast_time, fast_infos = _episode(config, nearest)
    slow, slow_time, slow_infos = _episode(config, farthest)
    assert fast_infos[-1]["end_reason"] == "explored"
    assert fast_time < slow_time and fast > slow
    # The return is the episode's time and decisions in seconds' worth, scaled.
    cfg = config.reward
    for infos, ret in ((fast_infos, fast), (slow_infos, slow)):
        seconds = sum(-i["dt_s"] - cfg.decision_s + cfg.gain_s_per_m2 * i["gain_m2"]
                      + i["completion_s"] - i["shortfall_s"] for i in infos)
        assert ret == pytest.approx(cfg.time_scale * seconds)
    assert fast_infos[-1]["completion_s"] == cfg.completion_s
    # The paper reward is the same episode's four terms.
    paper = dataclasses.replace(config, reward=RewardConfig(kind="paper"))
    _, paper_time, paper_infos = _episode(paper, nearest)
    assert paper_time == fast_time
    assert "completion_s" not in paper_infos[-1]


def test_time_reward_charges_a_short_end_and_a_wasted_decision():
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), observation=V2,
                                   episode=dataclasses.replace(FAST, max_time=10.0)))
    obs, _ = env.reset(seed=0)
    cfg = env.config.reward
    padding = int(np.flatnonzero(obs["node_mask"] == 0)[0])
    _, reward, *_, info = env.step(padding)
    assert info["invalid_action"] and reward == pytest.approx(-cfg.time_scale * cfg.decision_s)
    done = False
    while not done:
        _, reward, term, trunc, info = env.step(int(np.flatnonzero(env.action_masks())[0]))
        done = term or trunc
    assert info["end_reason"] == "time_limit"
    unexplored = 1.0 - info["exploration_ratio"] / FAST.target_ratio
    assert info["shortfall_s"] == pytest.approx(cfg.shortfall_s * unexplored)
    assert info["shortfall_s"] > 100.0  # Far from explored after 10 s.


# ----------------------------------------------------------------------------- observation


def _env_v2(seed: int = 1, steps: int = 2) -> tuple[ExplorationEnv, dict]:
    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, observation=V2))
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        obs, *_ = env.step(int(np.flatnonzero(env.action_masks())[0]))
    return env, obs


def test_v2_env_passes_the_env_checkers():
    import warnings

    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, observation=V2,
                                   max_decisions=4))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check(env, skip_render_check=True)
        sb3_check(env, warn=True)
    assert not caught, [str(w.message) for w in caught]
    assert env.observation_space["node_features"].shape == (V2.max_nodes * 9,)


def test_path_feature_is_the_costmap_distance_at_the_node():
    env, obs = _env_v2()
    state = env.episode.decision_state()
    features = obs["node_features"].reshape(V2.max_nodes, -1)
    real = obs["node_mask"] > 0
    distances = state.costmap.distances_from(state.pose[:2])
    grid = state.grid
    half = round(V2.path_radius / grid.resolution)
    expected = []
    for xy in env.decisions.padded.node_positions[real]:
        r, c = grid.world_to_cell(xy)
        expected.append(distances[max(r - half, 0):r + half + 1,
                                  max(c - half, 0):c + half + 1].min())
    expected = np.array(expected)
    reachable = np.isfinite(expected)
    assert reachable.sum() > 10 and np.ptp(expected[reachable]) > 3.0
    np.testing.assert_allclose(features[real, PATH][reachable], expected[reachable],
                               rtol=1e-6)
    np.testing.assert_array_equal(features[real, UNREACHABLE], ~reachable)
    assert np.all(features[real, PATH][~reachable] == 0)
    assert np.all(features[~real] == 0)
    robot = features[real, 5] == 0  # flag: the robot node
    assert features[real, PATH][robot] == pytest.approx(0.0, abs=0.1)


def test_blacklist_flag_marks_the_nodes_at_a_given_up_goal():
    env, obs = _env_v2(steps=1)
    features = obs["node_features"].reshape(V2.max_nodes, -1)
    assert not features[:, BLACKLISTED].any()
    valid = np.flatnonzero(env.action_masks())
    node = int(valid[0])
    ep = env.episode
    goal = env.decisions.padded.node_positions[node].astype(float)
    ep.blacklist.add(goal, "no_path", ep.mapper.grid)
    env.decisions.prepare(ep.decision_state())
    features = env.decisions.observation()["node_features"].reshape(V2.max_nodes, -1)
    positions = env.decisions.padded.node_positions
    real = env.decisions.padded.node_mask > 0
    near = np.linalg.norm(positions - goal, axis=1) <= ep.config.blacklist.radius
    assert features[node, BLACKLISTED] == 1.0 and not env.action_masks()[node]
    np.testing.assert_array_equal(features[real, BLACKLISTED] > 0, near[real])


def test_memory_pose_places_an_old_ter_in_the_current_frame():
    # Stored at A = (1, 2, pi/2) with the chosen node 1 m ahead: at (1, 3) in the map.
    # Now at B = (3, 3, pi): A lies 2 m ahead and 1 m to the left, turned -pi/2, and the
    # node 2 m straight ahead.
    memory = TerMemory(SMALL_V2)
    n, k = SMALL_V2.max_nodes, SMALL_V2.max_neighbours
    features = np.zeros((n, SMALL_V2.num_features), np.float32)
    features[:2, :2] = [[0.0, 0.0], [1.0, 0.0]]
    current = {"node_features": features, "neighbours": np.full((n, k), -1.0, np.float32),
               "node_mask": (np.arange(n) < 2).astype(np.float32)}
    memory.remember(current, 1, np.array([1.0, 2.0, math.pi / 2]))
    obs = memory.observation(current, np.array([3.0, 3.0, math.pi]))
    pose = obs["memory_pose"].reshape(-1, 3)
    np.testing.assert_allclose(pose[-1], [2.0, 1.0, -math.pi / 2], atol=1e-6)
    assert not pose[:-1].any()  # Empty slots.
    np.testing.assert_allclose(poses_in_frame(np.array([3.0, 3.0, math.pi]),
                                              np.array([[3.0, 3.0, math.pi]])), 0, atol=1e-12)
    place = memory_pose_features(torch.as_tensor(pose),
                                 torch.as_tensor(obs["memory_node_features"]).view(
                                     SMALL_V2.memory_length, n, -1),
                                 torch.as_tensor(obs["memory_choice"]))[-1]
    np.testing.assert_allclose(place.numpy(), [0.2, 0.1, 0.0, -1.0, 0.2, 0.0], atol=1e-6)


def test_memory_pose_follows_the_robot_in_the_env():
    env, obs = _env_v2(steps=3)
    assert obs["memory_mask"][-3:].all()
    stored = env.decisions.memory._pose[-3:]
    now = env.episode.sim.pose
    np.testing.assert_allclose(obs["memory_pose"].reshape(-1, 3)[-3:],
                               poses_in_frame(now, stored), atol=1e-5)
    assert np.linalg.norm(stored[-1, :2] - stored[0, :2]) > 0.5  # The robot moved.


# ----------------------------------------------------------------------------- network


def _permute(obs: dict[str, torch.Tensor], sigma: np.ndarray,
             n: int) -> dict[str, torch.Tensor]:
    """Observation 0 of a batch with its current TER's node i moved to slot sigma[i]."""
    out = {k: v[:1].clone() for k, v in obs.items()}
    f = obs["node_features"].shape[-1] // n
    feats = obs["node_features"][0].view(n, f)
    neigh = obs["neighbours"][0].view(n, -1)
    mask = obs["node_mask"][0]
    s = torch.as_tensor(sigma)
    new_feats, new_neigh, new_mask = (torch.zeros_like(feats), torch.full_like(neigh, -1.0),
                                      torch.zeros_like(mask))
    new_feats[s] = feats
    new_mask[s] = mask
    new_neigh[s] = torch.where(neigh >= 0, s[neigh.long().clamp(min=0)].float(), -1.0)
    out["node_features"] = new_feats.reshape(1, -1)
    out["neighbours"] = new_neigh.reshape(1, -1)
    out["node_mask"] = new_mask[None]
    return out


def test_v2_network_is_permutation_equivariant_over_nodes():
    policy = _policy(SMALL_V2)
    obs = _random_obs(SMALL_V2, 3, np.random.default_rng(5))
    n = SMALL_V2.max_nodes
    sigma = np.random.default_rng(1).permutation(n)  # Padding moves between real nodes too.
    permuted = _permute(obs, sigma, n)
    first = {k: v[:1] for k, v in obs.items()}
    with torch.no_grad():
        logits = policy.mlp_extractor.forward_actor(policy.extract_features(first))[0]
        moved = policy.mlp_extractor.forward_actor(policy.extract_features(permuted))[0]
        values = policy.predict_values(first), policy.predict_values(permuted)
    real = obs["node_mask"][0] > 0
    torch.testing.assert_close(moved[torch.as_tensor(sigma)][real], logits[real],
                               atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(*values, atol=1e-5, rtol=1e-5)
    # Not trivially equivariant: the logits differ between nodes.
    assert logits[real].std() > 1e-4


def test_inference_reuses_encoded_ters_until_the_weights_change(monkeypatch):
    policy = _policy(SMALL_V2)
    gvn = policy.features_extractor.gvn
    encoded = []
    rows = gvn.spatial.rows

    def counted_rows(features, neighbours, node_mask):
        encoded.append(len(node_mask))
        return rows(features, neighbours, node_mask)

    monkeypatch.setattr(gvn.spatial, "rows", counted_rows)
    obs = _random_obs(SMALL_V2, 4, np.random.default_rng(3))

    def features(grad: bool) -> torch.Tensor:
        with torch.set_grad_enabled(grad):
            return policy.extract_features(obs).detach()

    reference = features(True)
    first, again = features(False), features(False)
    assert encoded[1] > 0 and encoded[2:] == []  # The second call encodes nothing.
    torch.testing.assert_close(first, reference, atol=1e-5, rtol=1e-5)
    assert torch.equal(again, first)
    with torch.no_grad():
        gvn.spatial.layers[0].self_weight.weight.add_(0.5)  # As an optimizer step does.
    changed = features(False)
    torch.testing.assert_close(changed, features(True), atol=1e-5, rtol=1e-5)
    assert not torch.allclose(changed, first, atol=1e-3)
    gvn.encoded = EncodedTers(capacity=1)  # Fewer entries than one batch's TERs.
    torch.testing.assert_close(features(False), changed)
    assert len(gvn.encoded.entries) == 1


def test_batched_attention_equals_each_sample_attended_alone():
    # GVN.attend runs a batch's samples in size groups; each sample's rows must be what
    # attending to that sample alone gives (an empty sample included).
    from mjexplore.policies.gvn import ATTENTION_GROUPS

    gvn = _policy(SMALL_V2).features_extractor.gvn
    n, d = SMALL_V2.max_nodes, gvn.config.hidden
    counts = [3, 0, n, 1, 7, 2, 5, n - 1, 4, 0]
    assert len(counts) > ATTENTION_GROUPS
    node_mask = torch.zeros(len(counts), n)
    for i, c in enumerate(counts):
        node_mask[i, :c] = 1
    real_rows = (node_mask.reshape(-1) > 0).nonzero().squeeze(1)
    gen = torch.Generator().manual_seed(0)
    rows = torch.randn(len(real_rows), d, generator=gen)
    h = torch.randn(len(counts), d, generator=gen)
    with torch.no_grad():
        batched = gvn.attend(rows, real_rows, node_mask, h)
        start = 0
        for i, c in enumerate(counts):
            if not c:
                continue
            alone = gvn.attend_dense(rows[None, start:start + c], torch.ones(1, c, dtype=bool),
                                     h[i:i + 1])[0]
            torch.testing.assert_close(batched[start:start + c], alone, atol=1e-5, rtol=1e-5)
            start += c
        # No samples, or none with a node: no rows.
        for b in (0, 2):
            assert gvn.attend(rows[:0], real_rows[:0], torch.zeros(b, n), h[:b]).shape == (0, d)


def test_v2_uses_edge_lengths_and_global_attention():
    from mjexplore.policies.gvn import LENGTH_BASIS, EdgeMessages, LengthConv

    policy = _policy(SMALL_V2)
    gvn = policy.features_extractor.gvn
    assert len(gvn.global_attention) == 1
    obs = _random_obs(SMALL_V2, 1, np.random.default_rng(2))
    n = SMALL_V2.max_nodes
    # Without a single edge, a node still sees the others through attention.
    cut = {**obs, "neighbours": torch.full_like(obs["neighbours"], -1.0)}
    changed = cut["node_features"].view(n, -1).clone()
    changed[0, 2] += 5.0  # Node 0's gain only.
    last = int(obs["node_mask"][0].sum()) - 1
    with torch.no_grad():
        z1 = gvn(cut)[0][0, last]
        z2 = gvn({**cut, "node_features": changed.reshape(1, -1)})[0][0, last]
    assert not torch.allclose(z1, z2)
    # A message depends on its edge's length; a node without edges gets none.
    torch.manual_seed(0)
    layer = LengthConv(4, 8)
    h = torch.randn(3, 4)
    target = torch.tensor([[2, 0], [1, 0], [0, 0]])  # 1-based rows: 0-1 joined, 2 alone
    lengths = torch.tensor([[0.5, 0.0], [0.5, 0.0], [0.0, 0.0]])  # metres
    basis = [torch.tensor(b) for b in LENGTH_BASIS]
    for sparse in (False, True):
        with torch.no_grad():
            near = layer(h, EdgeMessages(target, lengths, *basis, sparse=sparse))
            far = layer(h, EdgeMessages(target, lengths * 12, *basis, sparse=sparse))
        assert not torch.allclose(near[:2], far[:2]) and torch.equal(near[2], far[2])
        torch.testing.assert_close(near[2], layer.self_weight(h[2]).detach())


def test_sparse_messages_give_the_gathered_forms_loss_and_gradients(monkeypatch):
    """The v2 encoder's training form of its messages (a sparse product) against the
    gathered form (what ONNX exports, and the only form before): one batch's values,
    log-probabilities, entropy and every parameter's gradient."""
    import mjexplore.policies.gvn as gvn_module

    config = dataclasses.replace(SMALL_V2, max_nodes=40, max_neighbours=4)
    obs, masks = _random_obs(config, 16, np.random.default_rng(5), valid=True)
    # Repeated TERs (as in a minibatch of consecutive decisions), and a sample without nodes.
    obs = {k: torch.cat([v, v[:4]]) for k, v in obs.items()}
    masks = torch.cat([masks, masks[:4]])
    obs["node_mask"][3] = 0.0
    actions = torch.multinomial(masks.float(), 1).squeeze(1)
    sparse_forms = []
    built = gvn_module.EdgeMessages.__init__

    def build(self, *args, sparse):
        sparse_forms.append(sparse)
        built(self, *args, sparse=sparse and form == "sparse")

    monkeypatch.setattr(gvn_module.EdgeMessages, "__init__", build)
    results = {}
    for form in ("gathered", "sparse"):
        policy = _policy(config, share_features_extractor=False)
        values, log_prob, entropy = policy.evaluate_actions(obs, actions, masks)
        (values.sum() + log_prob.sum() + entropy.sum()).backward()
        results[form] = [values, log_prob, entropy] + [p.grad for p in policy.parameters()]
    assert all(sparse_forms)  # Training takes the sparse form.
    # Float32 sums in another order: differences of the order of the largest gradient's
    # rounding (a gradient that is zero in exact arithmetic is that noise).
    scale = max(float(t.detach().abs().max()) for t in results["gathered"])
    for gathered, sparse in zip(results["gathered"], results["sparse"], strict=True):
        torch.testing.assert_close(sparse, gathered, atol=1e-5 * scale, rtol=1e-4)


def test_update_logits_run_the_actor_on_the_nodes_with_features_only():
    """GvnHeads.node_logits where gradients are taken (the actor's MLP on the rows of z
    that are not all zero) against the MLP on every row: logits and gradients."""
    heads = _policy(SMALL_V2).mlp_extractor
    z = torch.randn(6, SMALL_V2.max_nodes, 16, generator=torch.Generator().manual_seed(4))
    z[:, 7:] = 0.0  # Padding slots...
    z[2] = 0.0  # ...a TER without nodes...
    z[3, 1] = 0.0  # ...and a node whose features are all zero.
    results = []
    for logits in (lambda z: heads.actor(z).squeeze(-1), heads.node_logits):
        heads.zero_grad()
        leaf = z.clone().requires_grad_()
        out = logits(leaf)
        (out * torch.arange(out.numel()).view(out.shape).sin()).sum().backward()
        results.append([out, leaf.grad] + [p.grad.clone() for p in heads.actor.parameters()])
    for dense, live in zip(*results, strict=True):
        torch.testing.assert_close(live, dense, atol=1e-6, rtol=1e-5)
    with torch.no_grad():  # Inference: every row, as before.
        assert torch.equal(heads.node_logits(z), heads.actor(z).squeeze(-1))


@pytest.mark.parametrize("config", [ObservationConfig(max_nodes=40, max_neighbours=4,
                                                      memory_length=4), SMALL_V2])
def test_initial_policy_is_near_uniform_over_valid_actions(config):
    obs, masks = _random_obs(config, 8, np.random.default_rng(3), valid=True)
    for gain, near in ((0.01, True), (2.0, False)):
        policy = _policy(config, actor_gain=gain)
        with torch.no_grad():
            entropy = policy.get_distribution(obs, action_masks=masks.numpy()).entropy()
        uniform = torch.log(masks.sum(-1).float())
        gap = (uniform - entropy).max()
        assert (gap < 0.01) == near, (gain, gap)


# ----------------------------------------------------------------------------- weights


def _fixed_v1_observation(config: ObservationConfig, seed: int = 7):
    """A fixed, plausible v1 observation (robot-relative positions, bearings, distances)."""
    rng = np.random.default_rng(seed)
    n, k = config.max_nodes, config.max_neighbours

    def graph(real):
        neigh = random_tree(rng, n, k, real)
        f = np.zeros((n, 6), np.float32)
        xy = rng.uniform(-12, 12, size=(real, 2))
        f[:real, 0:2] = xy
        f[:real, 2] = rng.uniform(0, 0.3, real)
        f[:real, 3] = np.arctan2(xy[:, 1], xy[:, 0])
        f[:real, 4] = np.hypot(xy[:, 0], xy[:, 1])
        f[:real, 5] = rng.choice([-1.0, 1.0], real)
        f[0, :] = 0.0
        m = np.zeros(n, np.float32)
        m[:real] = 1
        return {"node_features": f, "neighbours": neigh, "node_mask": m}

    memory = TerMemory(config)
    for _ in range(4):
        real = int(rng.integers(20, 60))
        memory.remember(graph(real), int(rng.integers(1, real)))
    g = graph(40)
    return memory.observation(g), g["node_features"][:, 5] > 0


# The shipped policy's outputs on that observation, recorded before the v2 changes.
SHIPPED_LOGITS = [-1.359203, -3.382669, -3.323225, -0.796995, -1.524618, -2.30529, -2.13642,
                  -2.47008, -2.310459, -1.353965, -3.789926, -0.682625, -2.502233, -3.090309,
                  -3.49041, -2.524861, -1.847081, -2.776411, -1.347314, -1.224076, -0.949937,
                  -1.299935, -2.683147, -1.920696, -0.68606, -1.796088, -2.68649, 0.059171,
                  -2.803336, -0.555511, -0.838037, -2.223403, -2.628601, -1.786726, -1.437892,
                  -2.841162, -1.750083, -2.138264, -1.559806, -0.032814]
SHIPPED_VALUE = 4.723474979400635
SHIPPED_ACTION = 27


@pytest.mark.skipif(not (REPO / "models" / "gvn_paper" / "policy.safetensors").is_file(),
                    reason="no shipped GVN weights")
def test_shipped_v1_weights_load_and_act_as_before():
    from mjexplore.policies.weights import load_policy

    policy, meta = load_policy(REPO / "models" / "gvn_paper" / "policy.safetensors", "gvn")
    assert meta["decisions"].config.features == "v1" and meta["decisions"].topology is None
    assert "memory_pose" not in meta["decisions"].observation_space.spaces
    obs, mask = _fixed_v1_observation(meta["decisions"].config)
    t = {k: torch.as_tensor(v)[None] for k, v in obs.items()}
    with torch.no_grad():
        logits = policy.mlp_extractor.forward_actor(policy.extract_features(t))[0]
        value = float(policy.predict_values(t)[0, 0])
    np.testing.assert_allclose(logits[:40].numpy(), SHIPPED_LOGITS, atol=2e-5)
    assert value == pytest.approx(SHIPPED_VALUE, abs=2e-5)
    action, _ = policy.predict(obs, deterministic=True, action_masks=mask)
    assert int(action) == SHIPPED_ACTION
    for path in sorted((REPO / "models").glob("*/policy.safetensors")):
        load_policy(path)  # Every shipped policy still loads.


def test_v2_weights_carry_their_features_and_topology(tmp_path):
    from mjexplore.episode import Episode
    from mjexplore.policies.gvn_explorer import GvnExplorer
    from mjexplore.policies.registry import layout_of
    from mjexplore.policies.weights import load_policy, save_policy_weights, weights_sha256
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.topology.pipeline import TopologyConfig
    from mjexplore.topology.ter import TerConfig

    topology = TopologyConfig(gain_radius=1.5, ter=TerConfig(gain_radius=3.0))
    env_config = EnvConfig(scenes=("train_loop",), observation=ObservationConfig(
        max_nodes=64, max_neighbours=4, memory_length=3, features="v2"),
        episode=dataclasses.replace(FAST, topology=topology))
    config = env_config.observation
    policy = _policy(config)
    path = tmp_path / "v2.safetensors"
    save_policy_weights(path, policy, "gvn", {"masking": "iam", "hidden": 16},
                        layout_of("gvn", env_config))
    loaded, meta = load_policy(path, "gvn")
    decisions = meta["decisions"]
    assert decisions.config == config and decisions.topology == topology
    assert loaded.features_extractor.gvn.config.features == "v2"
    obs, masks = _random_obs(config, 2, np.random.default_rng(0), valid=True)
    with torch.no_grad():
        torch.testing.assert_close(policy.predict_values(obs), loaded.predict_values(obs))
    # The explorer builds v2 observations with the stored settings and picks valid nodes.
    explorer = GvnExplorer(path)
    assert explorer.decisions.topology == topology
    chosen = []
    original = explorer.decisions.act

    def act(action):
        assert explorer.decisions.mask[action]
        chosen.append(action)
        return original(action)

    explorer.decisions.act = act
    metrics = Episode(resolve_scene("train_loop"), explorer, 0,
                      dataclasses.replace(FAST, max_time=40.0)).run().metrics
    assert len(chosen) >= 2
    assert metrics["weights_sha256"] == weights_sha256(path)  # Each run names its weights.
    assert explorer.decisions.memory._mask.sum() == min(len(chosen), config.memory_length)


# ----------------------------------------------------------------------------- selection


def test_model_selection_uses_held_out_layouts(tmp_path, caplog):
    from mjexplore.config import from_dict, to_dict
    from mjexplore.learning.train_config import EvalConfig, TrainConfig, load_train_config

    proc = ProceduralScenes(families=("loop", "rooms"), width=(12.0, 14.0),
                            height=(10.0, 12.0), cache_dir=str(tmp_path))
    first = heldout_scenes(proc, 2, seed=0)
    assert heldout_scenes(proc, 2, seed=0) == first and len(set(first)) == 2
    seeds = [int(Path(s).name.rsplit("_s", 1)[1]) for s in first]
    assert all(s >= HELDOUT_SEED_BASE for s in seeds)  # Training draws below 2**31 - 1.
    assert EvalConfig(procedural=proc, layouts=2).scene_list() == first
    unseen = EvalConfig(procedural=proc, layouts=1).unseen_scenes(2)
    assert unseen == (first[1], heldout_scenes(proc, 3, seed=0)[2])  # After the selection.
    with pytest.raises(ValueError, match="eval.procedural"):
        EvalConfig(scenes=("train_loop",)).unseen_scenes(2)
    test = EvalConfig(procedural=proc, layouts=1).test_scenes(2)
    assert EvalConfig(procedural=proc, layouts=2).test_scenes(2) == test  # Fixed, whatever
    test_seeds = [int(Path(s).name.rsplit("_s", 1)[1]) for s in test]  # the selection's size.
    assert all(s >= TEST_SEED_BASE for s in test_seeds) and not set(test) & set(first + unseen)
    with caplog.at_level(logging.WARNING, logger="mjexplore.learning.train_config"):
        EvalConfig(scenes=("office",))
    assert "office" in caplog.text and "eval.procedural" in caplog.text
    v2 = load_train_config(REPO / "training" / "gvn_v2.yaml")
    assert from_dict(TrainConfig, to_dict(v2)) == v2
    assert v2.eval.procedural is not None and v2.env.reward.kind == "time"
    assert v2.env.observation.features == "v2"
    assert max(v2.env.procedural.width) >= 40 and max(v2.env.procedural.height) >= 25
    shipped = load_train_config(REPO / "training" / "gvn.yaml")
    assert shipped.env.reward.kind == "paper" and shipped.env.observation.features == "v1"


@pytest.mark.slow  # An export takes 5-20 s on 2 cores.
@pytest.mark.parametrize("privileged", [False, True])
def test_v2_actor_exports_to_onnx_with_torchs_logits(tmp_path, privileged):
    from mjexplore.policies.onnx_export import (
        OnnxActor,
        export_onnx,
        record_decisions,
        torch_actor_logits,
    )
    from mjexplore.policies.registry import layout_of
    from mjexplore.policies.weights import load_policy, save_policy_weights

    # With privileged, the explorer (record_decisions) feeds zeros for the critic's
    # ground truth, and the exported actor takes no such input.
    config = ObservationConfig(max_nodes=128, max_neighbours=8, memory_length=4,
                               features="v2", privileged=privileged)
    weights, model = tmp_path / "v2.safetensors", tmp_path / "v2.onnx"
    # A residual policy: the nearest-node prior is part of the exported graph.
    save_policy_weights(weights, _policy(config, actor_gain=1.0, prior_temperature=1.0), "gvn",
                        {"masking": "iam", "hidden": 16, "actor_gain": 1.0,
                         "prior_temperature": 1.0},
                        layout_of("gvn", EnvConfig(scenes=("train_loop",), observation=config)))
    export_onnx(weights, model)
    obs, masks = record_decisions(weights, 6, "train_loop")
    assert "memory_pose" in obs and obs["memory_mask"][-1].sum() >= 3
    assert ("privileged" in obs) == privileged
    assert "privileged" not in OnnxActor(model).keys
    expected = torch_actor_logits(load_policy(weights)[0], obs, masks).numpy()
    logits, actions = OnnxActor(model)(obs, masks)
    np.testing.assert_allclose(logits, expected, atol=1e-4, rtol=0)
    assert actions.tolist() == expected.argmax(1).tolist()


@pytest.mark.parametrize("masking", ["iam", "naive"])
def test_a_critic_with_its_own_encoder_saves_loads_and_acts(tmp_path, masking):
    from mjexplore.policies.weights import load_policy, save_policy_weights

    config = ObservationConfig(max_nodes=16, max_neighbours=3, memory_length=3, features="v2")
    policy = _policy(config, masking=masking, share_features_extractor=False)
    assert policy.pi_features_extractor is not policy.vf_features_extractor
    obs, masks = _random_obs(config, 3, np.random.default_rng(1), valid=True)
    obs_t = {k: torch.as_tensor(v) for k, v in obs.items()}
    with torch.no_grad():
        actions, values, _ = policy(obs_t, deterministic=True, action_masks=masks)
    path = tmp_path / "separate.safetensors"
    save_policy_weights(path, policy, "gvn", {"masking": masking, "hidden": 16,
                                              "share_features_extractor": False},
                        {**dataclasses.asdict(config)})
    loaded, _ = load_policy(path, "gvn")
    assert not loaded.share_features_extractor
    with torch.no_grad():
        again, values_again, _ = loaded(obs_t, deterministic=True, action_masks=masks)
    torch.testing.assert_close(values, values_again)
    assert torch.equal(actions, again)
    # What the explorer and the ONNX check read: the actor's logits through its own encoder.
    from mjexplore.policies.weights import actor_logits

    with torch.no_grad():
        logits = actor_logits(loaded, obs_t)
        expected = loaded.get_distribution(obs_t).distribution.logits
    masked = torch.where(torch.as_tensor(masks), logits, torch.tensor(-1e8))
    assert torch.equal(masked.argmax(1), again)
    torch.testing.assert_close(torch.log_softmax(logits, 1), expected)


@pytest.mark.parametrize("share", [True, False])
def test_privileged_inputs_reach_the_critic_and_never_the_actor(share):
    config = dataclasses.replace(SMALL_V2, privileged=True)
    policy = _policy(config, prior_temperature=1.0, share_features_extractor=share)
    obs, masks = _random_obs(config, 3, np.random.default_rng(2), valid=True)
    assert (obs["privileged"] == 0).all()  # No ground truth outside the training env.
    other = {**obs, "privileged": torch.tensor([[1.5, 0.4], [0.2, 0.9], [3.0, 0.7]])}
    with torch.no_grad():
        logits = [policy.get_distribution(o).distribution.logits for o in (obs, other)]
        values = [policy.predict_values(o) for o in (obs, other)]
    assert torch.equal(*logits)
    assert (values[0] != values[1]).all()


def test_training_env_fills_in_the_ground_truth_for_the_critic():
    from mjexplore.envs.observation import privileged_features

    env = ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST,
                                   observation=dataclasses.replace(V2, privileged=True)))
    obs, info = env.reset(seed=1)
    assert env.observation_space["privileged"].contains(obs["privileged"])
    seen = [obs["privileged"]]
    for _ in range(4):
        obs, _, terminated, truncated, info = env.step(
            int(np.flatnonzero(env.action_masks())[0]))
        seen.append(obs["privileged"])
        if terminated or truncated:
            break
    ep = env.episode
    assert obs["privileged"][1] == pytest.approx(1.0 - info["exploration_ratio"], abs=1e-6)
    target = ep.config.target_ratio * ep.counter.total - ep.counter.count
    assert obs["privileged"][0] == pytest.approx(
        target * ep.mapper.grid.resolution ** 2 / 100.0, rel=1e-5)
    assert seen[0][0] > seen[-1][0] > 0.0 and seen[0][1] > seen[-1][1]
    np.testing.assert_array_equal(privileged_features(10, 10, 0.9, 0.01), [0.0, 0.0])


# ----------------------------------------------------------------------- nearest prior


def test_path_prior_prefers_the_nearest_reachable_allowed_node():
    from mjexplore.policies.gvn import path_prior

    features = torch.zeros(1, 4, SMALL_V2.num_features)
    features[0, :, PATH] = torch.tensor([3.0, 1.0, 0.5, 0.0])
    features[0, 2, BLACKLISTED] = 1.0  # The nearest is given up...
    features[0, 3, UNREACHABLE] = 1.0  # ...and the path-0 one cannot be reached.
    logits = path_prior(features, temperature=2.0)
    assert logits.argmax().item() == 1
    torch.testing.assert_close(logits[0, 0] - logits[0, 1], torch.tensor(-1.0))
    features[0, 0, PATH] = 900.0  # However far a reachable node, an excluded one is below.
    logits = path_prior(features, temperature=0.5)
    assert logits[0, 0] > logits[0, 2:].max()


def test_residual_policy_starts_as_the_nearest_node_rule_and_round_trips(tmp_path):
    from mjexplore.policies.weights import actor_logits, load_policy, save_policy_weights

    obs, masks = _random_obs(SMALL_V2, 16, np.random.default_rng(5), valid=True)
    features = obs["node_features"].reshape(16, SMALL_V2.max_nodes, -1)
    features[..., PATH] = features[..., PATH].abs()
    features[..., UNREACHABLE] = (features[..., UNREACHABLE] > 4).float()
    features[..., BLACKLISTED] = 0.0
    obs["node_features"] = features.reshape(16, -1)
    kwargs = {"masking": "iam", "hidden": 16, "share_features_extractor": False,
              "prior_temperature": 0.5}
    policy = _policy(SMALL_V2, **{k: v for k, v in kwargs.items() if k != "hidden"})
    with torch.no_grad():
        actions, _, _ = policy(obs, deterministic=True, action_masks=masks)
    cost = features[..., PATH] + 1e6 * features[..., UNREACHABLE]
    nearest = torch.where(masks, cost, torch.tensor(torch.inf)).argmin(1)
    assert torch.equal(actions, nearest)
    # Without the prior the same weights' near-uniform head picks other nodes.
    plain = _policy(SMALL_V2, masking="iam", share_features_extractor=False)
    with torch.no_grad():
        assert not torch.equal(plain(obs, deterministic=True, action_masks=masks)[0], nearest)
    path = tmp_path / "residual.safetensors"
    save_policy_weights(path, policy, "gvn", kwargs, {**dataclasses.asdict(SMALL_V2)})
    loaded, _ = load_policy(path, "gvn")
    with torch.no_grad():
        torch.testing.assert_close(actor_logits(loaded, obs), actor_logits(policy, obs))


def test_residual_scale_multiplies_the_networks_logits_and_round_trips(tmp_path):
    from mjexplore.policies.weights import actor_logits, load_policy, save_policy_weights

    obs, _ = _random_obs(SMALL_V2, 4, np.random.default_rng(6), valid=True)
    kwargs = {"masking": "iam", "share_features_extractor": False, "prior_temperature": 0.5}
    plain = _policy(SMALL_V2, **kwargs)
    scaled = _policy(SMALL_V2, **kwargs, residual_scale=20.0)
    scaled.load_state_dict(plain.state_dict())
    prior = plain.pi_features_extractor.prior_logits(obs)
    with torch.no_grad():
        near = prior > -100.0  # Excluded nodes' logits (-4e4) keep ~4e-3 of a residual.
        residual = (actor_logits(plain, obs) - prior)[near]
        assert near.sum() > 4 and residual.abs().max() > 1e-4  # A residual to scale.
        torch.testing.assert_close((actor_logits(scaled, obs) - prior)[near], 20.0 * residual,
                                   rtol=1e-4, atol=1e-4)
    path = tmp_path / "scaled.safetensors"
    save_policy_weights(path, scaled, "gvn", {**kwargs, "hidden": 16, "residual_scale": 20.0},
                        {**dataclasses.asdict(SMALL_V2)})
    loaded, _ = load_policy(path, "gvn")
    with torch.no_grad():
        torch.testing.assert_close(actor_logits(loaded, obs), actor_logits(scaled, obs))


def test_entropy_relative_to_the_prior_is_minus_the_kl_and_pulls_toward_it():
    from mjexplore.policies.sb3 import kl_to_prior
    from mjexplore.policies.weights import actor_logits

    obs, masks = _random_obs(SMALL_V2, 6, np.random.default_rng(9), valid=True)
    kwargs = {"masking": "iam", "share_features_extractor": False, "prior_temperature": 0.5}
    plain = _policy(SMALL_V2, **kwargs)
    with torch.no_grad():  # A residual of a nat or so, not the initial head's 1e-2.
        plain.mlp_extractor.actor[-1].weight.mul_(100.0)
    anchored = _policy(SMALL_V2, **kwargs, entropy_reference="prior")
    anchored.load_state_dict(plain.state_dict())
    actions = torch.as_tensor([int(np.flatnonzero(m)[0]) for m in masks.numpy()])
    values, log_prob, entropy = plain.evaluate_actions(obs, actions, masks)
    a_values, a_log_prob, relative = anchored.evaluate_actions(obs, actions, masks)
    torch.testing.assert_close(a_values, values)
    torch.testing.assert_close(a_log_prob, log_prob)
    # -KL by hand over the valid nodes, the prior renormalised on them.
    prior = plain.pi_features_extractor.prior_logits(obs)
    with torch.no_grad():
        logits = actor_logits(plain, obs)
    expected = []
    for row in range(len(masks)):
        valid = masks[row]
        log_p = torch.log_softmax(logits[row][valid].double(), 0)
        log_q = torch.log_softmax(prior[row][valid].double(), 0)
        expected.append(-(log_p.exp() * (log_p - log_q)).sum())
    # Rows whose valid nodes are all excluded (logits near -8e4) keep float32's 8e-3 steps.
    near = torch.stack([prior[r][masks[r]].max() > -100.0 for r in range(len(masks))])
    assert near.sum() >= 4
    torch.testing.assert_close(relative.detach().double()[near], torch.stack(expected)[near],
                               rtol=1e-4, atol=1e-5)
    assert relative.max() <= 1e-6 and relative.min() < -1e-2  # A residual it measures.
    assert not torch.allclose(relative, entropy)
    # The policy equal to its prior: no divergence.
    log_prior = torch.log_softmax(prior.masked_fill(~masks, -1e8), -1)
    assert kl_to_prior(log_prior, prior, masks).abs().max() < 1e-5
    # Its gradient shrinks the residual: one step down the KL brings the policy nearer.
    optimizer = torch.optim.SGD(anchored.parameters(), lr=1e-2)
    (-relative.mean()).backward()
    optimizer.step()
    after = anchored.evaluate_actions(obs, actions, masks)[2]
    assert after.mean() > relative.mean()
    with pytest.raises(ValueError, match="prior_temperature"):
        _policy(SMALL_V2, masking="iam", entropy_reference="prior")
    with pytest.raises(ValueError, match="entropy_reference"):
        _policy(SMALL_V2, **kwargs, entropy_reference="uniformly")


def test_prior_kl_takes_the_entropy_bonus_place():
    from mjexplore.learning.train_config import load_train_config

    config = load_train_config(REPO / "training" / "gvn_anchor.yaml")
    assert config.ppo.prior_kl > 0 and config.ppo.ent_coef == 0
    with pytest.raises(ValueError, match="ent_coef"):
        dataclasses.replace(config.ppo, ent_coef=0.01)
    with pytest.raises(ValueError, match="target_kl"):
        dataclasses.replace(config.ppo, target_kl=0.0)
    with pytest.raises(ValueError, match="prior_kl needs"):
        dataclasses.replace(config, policy=dataclasses.replace(config.policy,
                                                               prior_temperature=None,
                                                               prior_pocket_m=0.0))


def test_prior_needs_the_v2_path_feature():
    from mjexplore.learning.train_config import load_train_config

    with pytest.raises(ValueError, match="v2"):
        _policy(ObservationConfig(max_nodes=12, max_neighbours=3, memory_length=4),
                prior_temperature=1.0)
    config = load_train_config(Path(__file__).parents[1] / "training" / "gvn.yaml")
    with pytest.raises(ValueError, match="prior_temperature"):
        dataclasses.replace(config, policy=dataclasses.replace(config.policy,
                                                               prior_temperature=1.0))


def test_nearest_node_rule_takes_the_nearest_valid_reachable_node():
    from mjexplore.learning.evaluation import NearestNodeRule

    features = np.zeros((SMALL_V2.max_nodes, SMALL_V2.num_features), np.float32)
    features[:4, PATH] = [0.5, 2.0, 1.0, 0.2]
    features[3, UNREACHABLE] = 1.0
    obs = {"node_features": features.reshape(-1), "node_mask": (np.arange(12) < 4) * 1.0}
    valid = np.array([False, True, True, True] + [False] * 8)  # Node 0 is not a frontier.
    assert NearestNodeRule().predict(obs, action_masks=valid)[0] == 2


def test_actor_logits_run_the_actors_encoder_alone_and_match_sb3s_distribution(monkeypatch):
    from mjexplore.policies.weights import actor_logits, load_policy

    policy, _ = load_policy(REPO / "models" / "gvn_v2" / "policy.safetensors")
    assert not policy.share_features_extractor  # The critic has an encoder of its own.
    obs = {k: torch.as_tensor(v)[None]
           for k, v in policy.observation_space.sample().items()}
    with torch.no_grad():
        expected = policy.get_distribution(obs).distribution.probs
        calls = []
        monkeypatch.setattr(policy.vf_features_extractor, "forward",
                            lambda o: calls.append(o) or torch.zeros(1))
        logits = actor_logits(policy, obs)
    assert not calls
    torch.testing.assert_close(torch.softmax(logits, -1), expected)
