"""The team as a PettingZoo ParallelEnv (its API test), its decisions one at a time as a
Gymnasium env, and a team trained by ``mjexplore train`` on SB3."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from mjexplore.envs.team import TeamExplorationEnv
from mjexplore.episode import EpisodeConfig
from mjexplore.errors import UserInputError
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


def test_the_team_decides_in_turn_in_one_gymnasium_env():
    """``TeamDecisionEnv``: one policy's steps are each robot's decisions in turn."""
    from mjexplore.envs.exploration import EnvConfig
    from mjexplore.envs.observation import ObservationConfig
    from mjexplore.envs.team_gvn import TeamDecisionEnv

    config = EnvConfig(scenes=("train_loop",), robots=2, max_decisions=40,
                       observation=ObservationConfig(max_nodes=64, max_neighbours=4,
                                                     memory_length=3),
                       episode=EpisodeConfig(sim=SimConfig(dynamics="kinematic"),
                                             max_time=120.0))
    env = TeamDecisionEnv(config)
    obs, info = env.reset(seed=0)
    deciders, rewards = [], []
    for _ in range(30):
        assert env.observation_space.contains(obs)
        mask = env.action_masks()
        assert mask.any() and np.array_equal(mask, obs["action_mask"].astype(bool))
        deciders.append(info["robot"])
        obs, reward, terminated, truncated, info = env.step(int(np.flatnonzero(mask)[0]))
        rewards.append(reward)
        if terminated or truncated:
            assert info["episode_metrics"]["robots"] == 2
            break
    assert {"robot_0", "robot_1"} <= set(deciders)
    assert any(r != 0.0 for r in rewards)
    with pytest.raises(UserInputError, match="robots"):
        EnvConfig(scenes=("train_loop",), robots=2, decisions="grid")


@pytest.mark.slow
def test_mjexplore_train_trains_a_team_on_sb3(tmp_path):
    """A team trains with ``mjexplore train`` (MaskablePPO, one policy shared by the
    robots) and gives a policy file like a single robot's."""
    import subprocess
    import sys

    from mjexplore.policies.weights import load_policy

    cfg = tmp_path / "team.yaml"
    cfg.write_text(TEAM_RECIPE)
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "mjexplore.cli", "train", "--no-progress",
                        "--config", str(cfg), "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[-1])["num_timesteps"] == 16
    _, meta = load_policy(out / "policy.safetensors", expected_kind="gvn")
    assert meta["layout"]["max_nodes"] == 64


TEAM_RECIPE = """
kind: gvn
total_steps: 16
n_envs: 1
checkpoint_every: 8
env:
  scenes: [train_loop]
  max_decisions: 12
  robots: 2
  observation: {max_nodes: 64, max_neighbours: 4, memory_length: 3}
  episode:
    sim: {dynamics: kinematic}
policy: {hidden: 16}
ppo: {n_steps: 8, batch_size: 8, n_epochs: 1}
eval: {every: 0}
"""


@pytest.mark.parametrize("robots", [1, 2])
def test_spaces_are_fixed_objects(robots):
    env = _env(robots=robots)
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent).n == env.k


def test_a_team_policy_is_evaluated_on_team_episodes(tmp_path):
    """Held-out evaluation of a team run (env.robots 2) runs team episodes, as it trains."""
    from mjexplore.learning.evaluation import evaluate_policy_episodes
    from mjexplore.learning.train_config import load_train_config

    class FirstValid:  # SB3's predict, the first valid node.
        def predict(self, obs, deterministic=True, action_masks=None):
            return int(np.flatnonzero(action_masks)[0]), None

    cfg = tmp_path / "team.yaml"
    cfg.write_text(TEAM_RECIPE.replace("eval: {every: 0}", "eval: {every: 0, scenes: [train_loop], "
                                       "episode: {max_time: 60.0, sim: {dynamics: kinematic}}}"))
    config = load_train_config(cfg)
    (result,) = evaluate_policy_episodes(FirstValid(), config)
    assert result["scene"] == "train_loop" and result["robots"] == 2
    assert len(result["per_robot"]) == 2
