"""The CNN baseline: grid observations, goal cells to reachable frontiers, training, acting."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mjexplore.envs import EnvConfig, ExplorationEnv, GridConfig
from mjexplore.envs.decisions import GRID_CHANNELS
from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.navigation.navigator import NavigatorConfig
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig

REPO = Path(__file__).resolve().parents[1]
FAST = EpisodeConfig(sim=SimConfig(dynamics="kinematic"),
                     navigator=NavigatorConfig(replan_rate_hz=0.5, replan_when_blocked=True))
GRID = GridConfig(image_size=32, action_cells=8)


def _env(**kw) -> ExplorationEnv:
    return ExplorationEnv(EnvConfig(scenes=("train_loop",), episode=FAST, decisions="grid",
                                    grid=GRID, **kw))


def test_grid_observation_shapes_and_value_ranges():
    env = _env()
    obs, _ = env.reset(seed=0)
    img = obs["image"].reshape(len(GRID_CHANNELS), 32, 32)
    assert obs["image"].dtype == np.float32 and env.observation_space.contains(obs)
    assert img.min() >= 0.0 and img.max() <= 1.0
    np.testing.assert_allclose(img[:3].sum(0), 1.0, atol=1e-5)  # free + occupied + unknown
    assert 0 < img[0].sum() < img[2].sum()  # Some free space seen, most still unknown.
    assert img[3].sum() == pytest.approx(9.0)  # The robot's 3 x 3 mark.
    mask = env.action_masks()
    assert mask.shape == (64,) and 0 < mask.sum() < 64
    for _ in range(4):
        obs, _, term, trunc, _ = env.step(int(np.flatnonzero(env.action_masks())[0]))
        if term or trunc:
            break
    assert obs["image"].reshape(5, 32, 32)[4].sum() > 0  # The trajectory channel fills.


def test_every_goal_cell_leads_to_a_reachable_frontier():
    env = _env()
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(4):
        d = env.decisions
        state = d._state
        reachable = np.isfinite(state.frontier_distances())
        goals = np.array([f.goal for f in state.frontiers])[reachable]
        for action in rng.choice(np.flatnonzero(env.action_masks()), 10):
            goal, waypoint = d.act(int(action))
            assert not waypoint
            assert np.min(np.linalg.norm(goals - goal, axis=1)) < 1e-9
        _, _, term, trunc, _ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))
        if term or trunc:
            break


@pytest.mark.slow
def test_cnn_trains_exports_and_acts(tmp_path):
    from mjexplore.learning.train_config import EvalConfig, PolicyConfig, PpoConfig, TrainConfig
    from mjexplore.learning.training import train
    from mjexplore.policies.cnn_explorer import CnnExplorer

    config = TrainConfig(kind="cnn", env=EnvConfig(scenes=("train_loop",), episode=FAST,
                                                   decisions="grid", grid=GRID,
                                                   max_decisions=10),
                         policy=PolicyConfig(features=32), ppo=PpoConfig(n_steps=8, batch_size=8,
                                                                         n_epochs=1),
                         eval=EvalConfig(every=0), total_steps=16, n_envs=1, checkpoint_every=8)
    summary = train(config, tmp_path / "run", progress=False)
    assert summary["num_timesteps"] == 16
    explorer = CnnExplorer(policy=tmp_path / "run" / "policy.safetensors")
    episode = Episode(resolve_scene("train_loop"), explorer, 0,
                      dataclasses.replace(FAST, max_time=40.0))
    result = episode.run()
    assert result.metrics["decisions"] >= 2 and result.metrics["exploration_ratio"] > 0.3


@pytest.mark.skipif(not (REPO / "models" / "cnn_paper" / "policy.safetensors").is_file(),
                    reason="no shipped CNN weights in training/")
def test_shipped_cnn_weights_load_and_act():
    from mjexplore.policies.cnn_explorer import CnnExplorer

    episode = Episode(resolve_scene("train_loop"), CnnExplorer(), 0,
                      dataclasses.replace(FAST, max_time=30.0))
    assert episode.run().metrics["decisions"] >= 1
