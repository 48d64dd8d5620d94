"""PPO minibatches of consecutive decisions (mjexplore/learning/rollout_blocks.py)."""

import dataclasses

import numpy as np
import pytest
import torch
from gymnasium import spaces

from mjexplore.learning.rollout_blocks import BlockDictRolloutBuffer, block_permutation
from mjexplore.learning.train_config import PpoConfig, TrainConfig


def test_block_permutation_visits_every_decision_once_in_runs_of_one_env():
    order = block_permutation(num_envs=3, num_steps=12, block=4, rng=np.random.default_rng(1))
    assert sorted(order) == list(range(36))
    runs = order.reshape(-1, 4)
    assert (np.diff(runs, axis=1) == 1).all()
    assert (runs[:, 0] % 4 == 0).all()  # A run never straddles two envs' rollouts.
    again = block_permutation(3, 12, 4, np.random.default_rng(1))
    other = block_permutation(3, 12, 4, np.random.default_rng(2))
    assert (order == again).all() and (order != other).any()
    with pytest.raises(ValueError, match="must divide the 12 steps"):
        block_permutation(3, 12, 5, np.random.default_rng(1))


def _filled_buffer(block: int, seed: int = 0) -> BlockDictRolloutBuffer:
    n_steps, n_envs = 8, 2
    observation_space = spaces.Dict({"step": spaces.Box(0, 100, (1,), np.float32),
                                     "env": spaces.Box(0, 100, (1,), np.float32)})
    buffer = BlockDictRolloutBuffer(n_steps, observation_space, spaces.Discrete(3),
                                    n_envs=n_envs, block=block, seed=seed)
    for step in range(n_steps):
        obs = {"step": np.full((n_envs, 1), step, np.float32),
               "env": np.arange(n_envs, dtype=np.float32)[:, None]}
        buffer.add(obs, np.zeros((n_envs, 1)), np.full(n_envs, 10.0 * step),
                   np.zeros(n_envs, bool), torch.zeros(n_envs), torch.zeros(n_envs),
                   action_masks=np.ones((n_envs, 3)))
    buffer.compute_returns_and_advantage(torch.zeros(n_envs), np.zeros(n_envs))
    return buffer


def test_buffer_minibatches_are_runs_of_consecutive_decisions_of_one_env():
    buffer = _filled_buffer(block=4)
    seen = []
    for batch in buffer.get(batch_size=8):
        step = batch.observations["step"].view(-1, 4).numpy()
        env = batch.observations["env"].view(-1, 4).numpy()
        assert (np.diff(step, axis=1) == 1).all() and (env == env[:, :1]).all()
        seen += list(zip(env.ravel(), step.ravel()))
    assert sorted(seen) == [(e, s) for e in (0.0, 1.0) for s in range(8)]
    # The second epoch draws the runs afresh; each sample keeps its own data.
    orders = [np.concatenate([b.observations["step"].view(-1).numpy()
                              + 8 * b.observations["env"].view(-1).numpy()
                              for b in buffer.get(batch_size=8)]) for _ in range(4)]
    assert any((o != orders[0]).any() for o in orders[1:])
    with pytest.raises(ValueError, match="minibatch size 6"):
        next(buffer.get(batch_size=6))
    with pytest.raises(ValueError, match="must divide the 8 steps"):
        _filled_buffer(block=3)


def test_minibatch_block_must_divide_the_rollout_and_the_minibatch():
    with pytest.raises(ValueError, match="must divide ppo.n_steps"):
        PpoConfig(n_steps=256, batch_size=128, minibatch_block=48)
    with pytest.raises(ValueError, match="ppo.minibatch_block must be >= 1"):
        PpoConfig(minibatch_block=0)
    base = TrainConfig()
    with pytest.raises(ValueError, match="for kind gvn"):
        TrainConfig(kind="cnn", env=dataclasses.replace(base.env, decisions="grid"),
                    ppo=PpoConfig(minibatch_block=2))
