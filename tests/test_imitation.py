"""Behaviour cloning of the ground-truth oracle and DAgger: the warm start before PPO."""

import json

import numpy as np
import pytest
import torch
from gymnasium import spaces

from mjexplore.envs import EnvConfig, ObservationConfig
from mjexplore.envs.observation import observation_space
from mjexplore.episode import EpisodeConfig
from mjexplore.learning.imitation import (
    ImitationConfig,
    clone,
    collect_expert_decisions,
    collect_learner_decisions,
    policy_learner,
    warm_start,
)
from mjexplore.learning.train_config import load_train_config
from mjexplore.learning.training import train
from mjexplore.policies.sb3 import GvnPolicy
from mjexplore.sim.simulator import SimConfig

SMALL = ObservationConfig(max_nodes=64, max_neighbours=4, memory_length=3, features="v2")
ENV = EnvConfig(scenes=("train_loop",), observation=SMALL, max_decisions=40,
                episode=EpisodeConfig(sim=SimConfig(dynamics="grid")))


def _fit(policy, obs, masks, actions) -> tuple[float, float]:
    """(share of decisions whose most likely action is the expert's, mean NLL of it)."""
    with torch.no_grad():
        dist = policy.get_distribution({k: torch.as_tensor(v) for k, v in obs.items()},
                                       action_masks=masks)
        nll = -dist.log_prob(torch.as_tensor(actions)).mean()
    return float((dist.distribution.probs.argmax(-1).numpy() == actions).mean()), float(nll)


def test_the_oracle_drives_the_env_and_the_policy_learns_its_choices():
    obs, masks, actions, stats = collect_expert_decisions(ENV, 2, seed=5)
    assert stats["decisions"] == len(actions) > 5 and stats["explored"] == 2
    assert masks[np.arange(len(actions)), actions].all()  # Every expert action is valid.
    torch.manual_seed(0)
    policy = GvnPolicy(observation_space(SMALL), spaces.Discrete(SMALL.max_nodes),
                       lambda _: 1e-3, hidden=16)
    agree0, nll0 = _fit(policy, obs, masks, actions)
    clone(policy, obs, masks, actions, ImitationConfig(episodes=2, epochs=30, batch_size=16))
    agree1, nll1 = _fit(policy, obs, masks, actions)
    assert nll1 < 0.7 * nll0  # The expert's choices became far likelier...
    assert agree1 >= agree0 + 0.15  # ...and more often the policy's own first choice.


def test_a_fresh_run_warm_starts_and_says_how_well(tmp_path):
    cfg = tmp_path / "bc.yaml"
    cfg.write_text("""
kind: gvn
total_steps: 8
n_envs: 1
checkpoint_every: 8
env:
  scenes: [train_loop]
  max_decisions: 12
  observation: {max_nodes: 64, max_neighbours: 4, memory_length: 3}
  episode:
    sim: {dynamics: grid}
policy: {hidden: 16}
ppo: {n_steps: 8, batch_size: 8, n_epochs: 1}
eval: {every: 0}
imitation: {episodes: 1, epochs: 2}
""")
    train(load_train_config(cfg), tmp_path / "run", progress=False)
    report = json.loads((tmp_path / "run" / "imitation.json").read_text())
    assert report["decisions"] > 0 and 0.0 <= report["agreement"] <= 1.0


# DAgger's tests: episodes of at most 6 decisions on the small loop.
SHORT = EnvConfig(scenes=("train_loop",), observation=SMALL, max_decisions=6,
                  episode=EpisodeConfig(sim=SimConfig(dynamics="grid")))


def _policy() -> GvnPolicy:
    torch.manual_seed(0)
    return GvnPolicy(observation_space(SMALL), spaces.Discrete(SMALL.max_nodes),
                     lambda _: 1e-3, hidden=16)


def test_dagger_aggregates_labelled_decisions_of_the_learners_own_rollouts():
    cfg = ImitationConfig(episodes=1, epochs=2, batch_size=16, seed=11, dagger_iterations=2)
    report = warm_start(_policy(), SHORT, cfg, seed=0)
    rounds = report["rounds"]
    assert [r["iteration"] for r in rounds] == [0, 1, 2]
    assert [r["beta"] for r in rounds] == [1.0, 0.0, 0.0]  # beta0 = 0: the learner alone.
    assert [r["expert_share"] for r in rounds] == [1.0, 0.0, 0.0]
    assert all(r["decisions"] > 0 and r["mean_exploration_time_s"] > 0 for r in rounds)
    assert all(0.0 <= r["agreement_before"] <= 1.0 for r in rounds)
    aggregate = np.cumsum([r["decisions"] for r in rounds])
    assert [r["aggregate"] for r in rounds] == aggregate.tolist()
    assert report["decisions"] == aggregate[-1] > rounds[0]["decisions"]
    assert report["episodes"] == 3 and 0.0 <= report["agreement"] <= 1.0
    assert report["observation_mib"] > 0


def test_departures_count_where_labels_and_learner_leave_the_prior():
    from mjexplore.learning.imitation import _probabilities, departures
    from mjexplore.policies.gvn import path_prior

    obs, masks, labels, _ = collect_expert_decisions(SHORT, 2, seed=5)
    torch.manual_seed(0)
    policy = GvnPolicy(observation_space(SMALL), spaces.Discrete(SMALL.max_nodes),
                       lambda _: 1e-3, hidden=16, prior_temperature=0.5,
                       share_features_extractor=False)
    features = torch.as_tensor(obs["node_features"]).reshape(len(masks), SMALL.max_nodes, -1)
    prior = np.where(masks, path_prior(features, 0.5).numpy(), -np.inf).argmax(1)
    labels = prior.copy()
    moved = [i for i in range(len(masks)) if masks[i].sum() > 1][:3]
    assert len(moved) == 3
    for i in moved:  # Three labels leave the prior for another valid node.
        labels[i] = next(a for a in np.flatnonzero(masks[i]) if a != prior[i])
    # The untrained network is its prior: it departs nowhere, so it takes no departure.
    stats = departures(policy, obs, masks, labels)
    assert stats["label_departs"] == pytest.approx(3 / len(labels))
    assert stats["learner_departs"] == 0.0 and stats["departure_precision"] is None
    assert stats["departure_recall"] == 0.0
    # A loud residual departs often; precision and recall as counted by hand.
    with torch.no_grad():
        policy.mlp_extractor.actor[-1].weight.mul_(1e4)
    learner = _probabilities(policy, obs, masks).argmax(1)
    departs = learner != prior
    assert departs.any()
    stats = departures(policy, obs, masks, labels)
    assert stats["learner_departs"] == pytest.approx(departs.mean())
    assert stats["departure_precision"] == pytest.approx((learner == labels)[departs].mean())
    assert stats["departure_recall"] == pytest.approx((learner == labels)[moved].mean())
    assert departures(_policy(), obs, masks, labels) == {}  # No prior, nothing to leave.


def _last_valid(obs, mask):
    """A learner that takes the valid action of the highest index (not the expert's way)."""
    del obs
    probs = np.zeros(len(mask))
    probs[np.flatnonzero(mask)[-1]] = 1.0
    return probs


def test_a_contrary_learners_states_get_the_experts_labels():
    obs, masks, labels, taken, stats = collect_learner_decisions(SHORT, _last_valid, 1, seed=5)
    n = stats["decisions"]
    assert n == len(labels) == len(taken) == len(masks) > 2 and stats["expert_share"] == 0.0
    last = np.array([np.flatnonzero(m)[-1] for m in masks])
    assert (taken == last).all()  # The learner drove the episode...
    assert masks[np.arange(n), labels].all()  # ...each state labelled with a valid action...
    assert (labels != taken).any()  # ...that is not simply the action taken...
    assert stats["agreement"] == pytest.approx(float((labels == taken).mean()))
    # ...but the expert's choice on the learner's state: the first state is the expert's own
    # first state (same layout and start), and the label the oracle's choice there.
    e_obs, _, e_actions, _ = collect_expert_decisions(SHORT, 1, seed=5)
    assert all(np.array_equal(obs[k][0], e_obs[k][0]) for k in obs)
    assert labels[0] == e_actions[0]
    # The later states are the learner's: not states of the expert's episode.
    key = "node_features"
    theirs = {e_obs[key][i].tobytes() for i in range(len(e_actions))}
    assert any(obs[key][i].tobytes() not in theirs for i in range(1, n))
    assert obs[key].dtype == np.float32


def test_without_dagger_rounds_the_warm_start_is_plain_cloning_bit_for_bit():
    cfg = ImitationConfig(episodes=1, epochs=2, batch_size=16, seed=7)
    plain = _policy()
    obs, masks, actions, stats = collect_expert_decisions(SHORT, cfg.episodes, cfg.seed)
    fit = clone(plain, obs, masks, actions, cfg, seed=3)
    started = _policy()
    assert warm_start(started, SHORT, cfg, seed=3) == {**stats, **fit}
    mine, theirs = started.state_dict(), plain.state_dict()
    assert mine.keys() == theirs.keys()
    assert all(torch.equal(mine[k], theirs[k]) for k in mine)
    # DAgger's rounds need the env: cloning alone refuses a config that asks for them.
    with pytest.raises(ValueError, match="warm_start"):
        clone(plain, obs, masks, actions, ImitationConfig(episodes=1, dagger_iterations=1))
    with pytest.raises(ValueError):
        ImitationConfig(dagger_iterations=1)  # No episodes per round.
    with pytest.raises(ValueError):
        ImitationConfig(episodes=1, dagger_iterations=1, beta0=1.5)


def test_rollouts_in_worker_processes_give_the_same_labelled_decisions():
    policy = _policy()  # Fitted once: a fitted policy crosses to the workers too.
    obs, masks, actions, _ = collect_expert_decisions(SHORT, 1, seed=3)
    clone(policy, obs, masks, actions, ImitationConfig(episodes=1, epochs=1, batch_size=4))
    learner = policy_learner(policy)
    serial = collect_learner_decisions(SHORT, learner, 2, seed=5, expert="lookahead")
    pooled = collect_learner_decisions(SHORT, learner, 2, seed=5, expert="lookahead", workers=2)
    for a, b in zip(serial[1:4], pooled[1:4]):
        assert np.array_equal(a, b)
    assert all(np.array_equal(serial[0][k], pooled[0][k]) for k in serial[0])
    assert serial[4] == pooled[4]


def test_the_lookahead_expert_labels_valid_nodes_and_explores():
    obs, masks, actions, stats = collect_expert_decisions(ENV, 1, seed=5, expert="lookahead")
    assert stats["explored"] == 1 and len(actions) > 3
    assert masks[np.arange(len(actions)), actions].all()
    with pytest.raises(ValueError, match="imitation.expert"):
        ImitationConfig(expert="tour")


def test_keeping_the_prior_labels_its_choice_unless_the_lookahead_saves_more():
    obs, masks, labels, _ = collect_expert_decisions(SHORT, 1, seed=5, expert="lookahead",
                                                     keep_prior=(1e9, 0.0))
    from mjexplore.learning.imitation import _prior_choice

    # Nothing saves a billion metres: every label is the nearest node's, as the prior picks.
    assert all(labels[i] == _prior_choice({k: v[i] for k, v in obs.items()}, masks[i], 0.0)
               for i in range(len(labels)))
    with pytest.raises(ValueError, match="keep_prior_m needs expert: lookahead"):
        ImitationConfig(keep_prior_m=5.0)


def test_the_margin_loss_is_zero_where_the_label_leads_and_pushes_it_ahead_elsewhere():
    from mjexplore.learning.imitation import margin_loss

    logits = torch.tensor([[3.0, 1.0, 0.0], [0.0, 2.0, 5.0], [1.0, 9.0, 0.0]],
                          requires_grad=True)
    masks = np.array([[True, True, False], [True, True, False], [True, False, False]])
    target = torch.tensor([0, 0, 0])
    loss = margin_loss(logits, masks, target, margin=1.0)
    # Row 0 leads by 2 (no loss); row 1 trails the valid rival by 2 (the invalid 5 does not
    # count): 3; row 2 has no valid rival: 0.
    assert float(loss.detach()) == pytest.approx(3.0 / 3)
    loss.backward()
    assert logits.grad[1, 0] < 0 < logits.grad[1, 1] and not logits.grad[0].any()
    assert not logits.grad[1, 2] and not logits.grad[2].any()
    with pytest.raises(ValueError, match="imitation.loss"):
        ImitationConfig(loss="hinge")
