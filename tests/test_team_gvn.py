"""The team's ParallelEnv with the single-robot GVN observation per robot (issue 37, item 4):
its API test, the shipped gvn_v3 policy acting per robot, the teammates' goals marked."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pettingzoo.test import parallel_api_test

from mjexplore.envs.team_gvn import (
    GOAL_KEY,
    TeamGvnEnv,
    single_robot_observation,
    teammate_goal_distance,
)
from mjexplore.episode import EpisodeConfig
from mjexplore.policies.gvn_explorer import GvnExplorer
from mjexplore.policies.weights import load_policy
from mjexplore.sim.simulator import SimConfig

POLICY = "models/gvn_v3/policy.safetensors"


@pytest.fixture(scope="module")
def gvn_v3():
    torch.set_num_threads(1)
    return load_policy(POLICY, expected_kind="gvn")


def _env(decisions=None, robots: int = 2, dynamics: str = "kinematic", **kwargs) -> TeamGvnEnv:
    config = EpisodeConfig(sim=SimConfig(dynamics=dynamics), max_time=60.0)
    layout = {} if decisions is None else {"observation": decisions.config,
                                           "topology": decisions.topology}
    return TeamGvnEnv("train_loop", robots=robots, config=config, **layout, **kwargs)


def test_parallel_api():
    parallel_api_test(_env(), num_cycles=15)


def test_observation_is_the_single_robot_one_with_the_team_keys(gvn_v3):
    _, meta = gvn_v3
    decisions = meta["decisions"]
    env = _env(decisions)
    obs, _ = env.reset(seed=0)
    single = decisions.observation_space
    for agent in env.agents:
        rest = single_robot_observation(obs[agent])
        assert set(rest) == set(single.spaces)
        assert single.contains(rest)
        assert env.observation_space(agent).contains(obs[agent])
        assert obs[agent]["action_mask"].any()


@pytest.mark.parametrize("dynamics", ["kinematic", "grid"])
def test_shipped_gvn_v3_explores_as_a_team(gvn_v3, dynamics):
    policy, meta = gvn_v3
    env = _env(meta["decisions"], dynamics=dynamics)
    obs, infos = env.reset(seed=0)
    chosen = 0
    while env.agents:
        actions = {}
        for agent in env.agents:
            mask = obs[agent]["action_mask"].astype(bool)
            action, _ = policy.predict(single_robot_observation(obs[agent]),
                                       deterministic=True, action_masks=mask)
            actions[agent] = int(action)
            if infos[agent]["deciding"] and mask.any():
                assert mask[actions[agent]]
                chosen += 1
        obs, rewards, terms, truncs, infos = env.step(actions)
    assert env.episode.end_reason == "explored"
    assert chosen >= 4
    # Every decision the policy made is in its robot's own episodic memory.
    assert all(d.memory._mask.sum() > 0 for d in env.decisions)
    assert sum(a.fallbacks for a in env.episode.agents) == 0


def test_first_choice_is_the_single_robot_gvn_explorers(gvn_v3):
    """On the team's map, an agent's observation makes the shipped policy choose what the
    deployed GVN explorer chooses from that robot's decision state."""
    policy, meta = gvn_v3
    env = _env(meta["decisions"])
    obs, _ = env.reset(seed=1)
    explorer = GvnExplorer("gvn_v3")
    for agent in env.episode.agents:
        name = env.possible_agents[agent.index]
        o = obs[name]
        action, _ = policy.predict(single_robot_observation(o), deterministic=True,
                                   action_masks=o["action_mask"].astype(bool))
        explorer.reset(np.random.default_rng(0))
        goal = explorer.select_goal(agent.decision_state())
        np.testing.assert_allclose(env.decisions[agent.index].padded.node_positions[action],
                                   goal)


def test_teammate_goal_key_marks_the_node_nearest_a_teammates_goal(gvn_v3):
    env = _env(gvn_v3[1]["decisions"])
    obs, infos = env.reset(seed=0)
    masks = {a: obs[a]["action_mask"] for a in env.agents}
    # Before any goal: nothing marked.
    assert all(np.all(obs[a][GOAL_KEY] == 5.0) for a in env.agents)
    obs, *_ = env.step({a: int(np.argmax(masks[a])) for a in env.agents})
    goal_1 = env.episode.agents[1].goal
    assert goal_1 is not None
    d = env.decisions[0]
    real = d.padded.node_mask > 0
    key = obs["robot_0"][GOAL_KEY]
    dist = np.linalg.norm(d.padded.node_positions[real] - goal_1, axis=1)
    if env.episode.agents[0].goal is not None:  # Robot 1 sees robot 0's goal, not its own.
        other = np.linalg.norm(env.decisions[1].padded.node_positions[
            env.decisions[1].padded.node_mask > 0] - env.episode.agents[0].goal, axis=1)
        np.testing.assert_allclose(obs["robot_1"][GOAL_KEY][:len(other)],
                                   np.minimum(other / 20.0, 5.0), rtol=1e-5)
    nearest = int(np.argmin(dist))
    assert int(np.argmin(np.where(real, key, np.inf))) == nearest
    assert key[nearest] == pytest.approx(min(dist[nearest] / 20.0, 5.0), rel=1e-5)
    assert dist[nearest] < 1.0  # The teammate's goal is (near) a node of this TER.
    assert np.all(key[~real] == 5.0)


def test_teammate_goal_distance_caps_and_pads():
    positions = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 0.0]])
    mask = np.array([1, 1, 0])
    np.testing.assert_allclose(teammate_goal_distance(positions, mask, []), [5, 5, 5])
    np.testing.assert_allclose(
        teammate_goal_distance(positions, mask, [np.array([0.0, 0.0]),
                                                 np.array([300.0, 0.0])]),
        [0.0, 0.25, 5.0])


def test_invalid_action_takes_the_nearest_frontier():
    env = _env()
    obs, _ = env.reset(seed=0)
    invalid = {a: int(np.flatnonzero(obs[a]["action_mask"] == 0)[0]) for a in env.agents}
    env.step(invalid)
    assert all(a.goals and a.goals[0][0] == 0.0 for a in env.episode.agents)  # Driven on.
    assert all(d.memory._mask.sum() == 0 for d in env.decisions)  # Nothing remembered.
