"""The team as a PettingZoo ParallelEnv (its API test) and independent PPO on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pettingzoo.test import parallel_api_test

from mjexplore.envs.team import TeamExplorationEnv
from mjexplore.episode import EpisodeConfig
from mjexplore.learning.team_ppo import TeamPPOConfig, train_independent_ppo
from mjexplore.sim.simulator import SimConfig


def _env(**kwargs) -> TeamExplorationEnv:
    config = EpisodeConfig(sim=SimConfig(dynamics="kinematic"), max_time=60.0)
    return TeamExplorationEnv("train_loop", config=config, **kwargs)


def test_parallel_api():
    parallel_api_test(_env(robots=2), num_cycles=30)


def test_episode_runs_to_its_end_with_decisions_as_robots_need_them():
    env = _env(robots=3)
    obs, infos = env.reset(seed=2)
    assert set(obs) == set(env.possible_agents) == {"robot_0", "robot_1", "robot_2"}
    assert all(infos[a]["deciding"] for a in env.agents)  # Every robot decides first.
    space = env.observation_space("robot_0")
    assert space.contains(obs["robot_0"])
    partial = 0
    steps = 0
    while env.agents:
        deciding = [a for a in env.agents if infos[a]["deciding"]]
        partial += 0 < len(deciding) < len(env.agents)
        actions = {a: int(np.argmax(obs[a]["action_mask"])) for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        steps += 1
        assert len(set(rewards.values())) <= 1  # One team reward.
    assert terms["robot_0"] or truncs["robot_0"]
    assert partial > 0  # Robots decide one at a time as well, not in lockstep.
    assert env.episode.end_reason == "explored"


def test_chosen_candidates_become_goals():
    env = _env(robots=2)
    obs, infos = env.reset(seed=0)
    cands = [c.copy() for c in env._candidates]
    mask = obs["robot_1"]["action_mask"]
    last = int(np.flatnonzero(mask)[-1])
    env.step({"robot_0": 0, "robot_1": last})
    np.testing.assert_allclose(env.episode.agents[1].goals[0][1:], cands[1][last])
    np.testing.assert_allclose(env.episode.agents[0].goals[0][1:], cands[0][0])


def test_independent_ppo_smoke():
    torch.set_num_threads(1)
    env = _env(robots=2)
    policies, log = train_independent_ppo(env, TeamPPOConfig(steps=32, rollout=16, seed=0))
    assert set(policies) == {"robot_0", "robot_1"}
    assert len(log) == 2
    for line in log:
        assert line["agents_updated"] == 2
        assert np.isfinite([line["policy_loss"], line["value_loss"], line["entropy"]]).all()
    assert policies["robot_0"].logit.weight.abs().sum() > 0
    # The two agents learn apart: their weights differ after training.
    a, b = (policies[k].logit.weight for k in ("robot_0", "robot_1"))
    assert not torch.allclose(a, b)


@pytest.mark.parametrize("robots", [1, 2])
def test_spaces_are_fixed_objects(robots):
    env = _env(robots=robots)
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent).n == env.k
