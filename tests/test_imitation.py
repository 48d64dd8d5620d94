"""Behaviour cloning of the ground-truth oracle: the warm start before PPO."""

import json

import numpy as np
import torch
from gymnasium import spaces

from mjexplore.envs import EnvConfig, ObservationConfig
from mjexplore.envs.observation import observation_space
from mjexplore.episode import EpisodeConfig
from mjexplore.learning.imitation import ImitationConfig, clone, collect_expert_decisions
from mjexplore.learning.training import load_train_config, train
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
