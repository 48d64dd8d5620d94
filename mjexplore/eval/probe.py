"""One episode of a training config's env, driven by a probe mode: what
``tools/probe_policy.py``, ``mjexplore plot-training`` (its baselines) and
``tools/research/dagger_probe.py`` run.

Modes (:data:`MODES`): ``policy`` (the trained policy's most probable valid action),
``random`` (a valid action drawn uniformly), ``greedy`` (the valid action nearest the robot:
along the known map with v2 or v3 GVN observations, else in a straight line) and ``prior``
(a residual policy's prior alone); any other name is a classic explorer's, which drives the
same episode (layout, start pose, seed and settings) on its own.
"""

from __future__ import annotations

MODES = ("policy", "random", "greedy", "prior")


def probe_config(config_path: str | None, weights: str):
    """The training config of ``--config``, or the one the weights were trained with."""
    from mjexplore.config import from_dict
    from mjexplore.learning.train_config import TrainConfig, load_train_config
    from mjexplore.policies.weights import read_policy_weights

    if config_path is not None:
        return load_train_config(config_path)
    return from_dict(TrainConfig, read_policy_weights(weights)[1]["provenance"]["config"])


def probe_episode(job: tuple[str | None, str, str, int, str | None]) -> dict:
    """One episode, ``job`` = (config path or None, weights, mode, seed, scene): the training
    env's layout of ``seed`` when ``scene`` is None, else that held-out layout; its
    :func:`episode_row`."""
    import numpy as np
    import torch

    from mjexplore.envs import ExplorationEnv
    from mjexplore.envs.observation import POSED
    from mjexplore.learning.evaluation import NearestNodeRule, heldout_env
    from mjexplore.policies.weights import load_policy

    config_path, weights, mode, seed, scene = job
    torch.set_num_threads(1)
    config = probe_config(config_path, weights)
    env = ExplorationEnv(config.env) if scene is None else heldout_env(config, scene)
    if mode not in MODES:  # A classic explorer on the episode the env would run.
        from mjexplore.episode import Episode
        from mjexplore.explorers import make_explorer

        env.reset(seed=seed)
        ep = env.episode
        assert ep is not None  # Made by reset.
        metrics = Episode(ep.scene, make_explorer(mode), ep.sim.config.seed,
                          ep.config).run().metrics
        return episode_row(mode, seed, scene, None, metrics)
    policy = load_policy(weights, expected_kind=config.kind)[0] if mode == "policy" else None
    along_map = config.env.observation.features in POSED and config.kind == "gvn"
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    episode = env.episode
    assert episode is not None  # Made by reset.
    total = 0.0
    done = info["end_reason"] is not None
    while not done:
        mask = env.action_masks()
        if policy is not None:  # mode "policy"
            action, _ = policy.predict(obs, deterministic=True, action_masks=mask)
        elif mode == "random":
            action = rng.choice(np.flatnonzero(mask))
        elif mode == "prior":
            rule = NearestNodeRule(config.policy.prior_pocket_m)
            action, _ = rule.predict(obs, action_masks=mask)
        elif along_map:
            action, _ = NearestNodeRule().predict(obs, action_masks=mask)
        else:
            distance = np.linalg.norm(env.decisions.action_positions()
                                      - episode.sim.pose[:2], axis=1)
            action = np.argmin(np.where(mask, distance, np.inf))
        obs, reward, terminated, truncated, info = env.step(int(action))
        total += reward
        done = terminated or truncated
    return episode_row(mode, seed, scene, total, episode.result().metrics)


def episode_row(mode: str, seed: int, scene: str | None, total: float | None,
                metrics: dict) -> dict:
    """What a probe keeps of an episode (``return`` None where an explorer drove it)."""
    return {"mode": mode, "seed": seed, "scene": scene, "return": total,
            "exploration_time_s": metrics["exploration_time_s"],
            "path_length_m": metrics["path_length_m"],
            "explored": metrics["end_reason"] == "explored"}
