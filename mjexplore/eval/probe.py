"""How much a trained policy has learned (``mjexplore probe-policy``, :func:`probe_policy`),
and one episode of a training config's env driven by a probe mode (:func:`probe_episode`:
what ``mjexplore probe-policy``, ``mjexplore plot-training`` (its baselines) and
``tools/research/dagger_probe.py`` run).

Modes (:data:`MODES`): ``policy`` (the trained policy's most probable valid action),
``random`` (a valid action drawn uniformly), ``greedy`` (the valid action nearest the robot:
along the known map with v2 or v3 GVN observations, else in a straight line) and ``prior``
(a residual policy's prior alone); any other name is a classic explorer's, which drives the
same episode (layout, start pose, seed and settings) on its own.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Sequence

from mjexplore.errors import UserInputError

MODES = ("policy", "random", "greedy", "prior")
DEFAULT_MODES = ("policy", "random", "greedy")


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


def probe_policy(weights: str, config: str | None = None, episodes: int = 10,
                 seed_base: int = 10_000, heldout: bool = False, unseen: int = 0,
                 modes: Sequence[str] = DEFAULT_MODES, workers: int = 2) -> dict:
    """How much a trained policy has learned: it against chance and a greedy rule, same layouts.

    Runs whole episodes of the training env of a config (its decision space, reward,
    procedural layouts and training-mode dynamics) with each mode choosing every action:

    * ``policy``: the trained policy, its most probable valid action (as the explorers use
      it);
    * ``random``: a valid action drawn uniformly (what an untrained policy amounts to);
    * ``greedy``: the valid action nearest the robot: with v2 or v3 observations the node
      nearest along the known map (:class:`~mjexplore.learning.evaluation.NearestNodeRule`,
      what nearest-frontier ranks by), otherwise the one placed nearest in a straight line
      (for the grid decisions, roughly the nearest frontier);
    * ``prior``: a residual policy's prior alone, its logits without the network's (v3: the
      nearest node counting each ``policy.prior_pocket_m`` metres farther per unit of its
      pocket probability; v2: as ``greedy``): what the network's residual adds is ``policy``
      against it.

    With ``heldout`` or ``unseen``, a classic explorer's name (``nearest``, ``oracle``, ...)
    is a mode too: that explorer drives the same episode (layout, start pose, seed and
    settings) on its own, a reference such as the ground-truth bound; it has no return.

    Every mode sees the same layouts and start poses: episode seed ``seed_base + i`` for
    ``i`` below ``episodes`` (training draws its layouts from the config's seed, so these are
    unseen layouts of the same distribution), or with ``heldout`` the config's
    model-selection layouts (``eval``: the generated layouts training never draws, its
    episode settings and seed; one episode each), or with ``unseen`` N > 0 the N generated
    layouts after those (the same generator seeds' sequence, seen by neither training nor
    model selection; evaluation settings as ``heldout``; ``unseen`` wins over ``heldout``).
    The episodes run in ``workers`` spawned processes, one per episode and mode at a time.

    ``mjexplore probe-policy --weights FILE [--config YAML] [--episodes N | --heldout |
    --unseen N] [--modes policy,random,greedy[,prior,nearest,oracle]] [--workers N]`` runs
    it and prints the figures as one JSON line.

    Args:
        weights: the exported policy (.safetensors).
        config: the training YAML whose env is used; None: the config stored with the
            weights.
        episodes: how many seeds (``seed_base`` on) without ``heldout`` or ``unseen``.
        seed_base: the first episode seed without ``heldout`` or ``unseen``.
        heldout: run the config's model-selection layouts instead of ``episodes`` seeds.
        unseen: when > 0, run this many generated layouts past the model-selection ones.
        modes: of :data:`MODES` and, with ``heldout`` or ``unseen``, classic explorer names.
        workers: processes running the episodes.

    Returns:
        ``config`` (its path, or "stored with the weights"), ``weights``, ``episodes`` (how
        many layouts) and ``layouts`` (which), then per mode its mean ``MODE_return`` (not
        for explorers), ``MODE_exploration_time_s`` (simulated s) and ``MODE_path_length_m``
        (rounded to 3 decimals) and ``MODE_explored`` (how many episodes ended explored);
        with ``policy``, ``random`` and ``greedy``: ``learned_fraction``, where the policy's
        mean return lies between random (0) and greedy (1) (None where they are equal);
        with ``policy`` and ``greedy``: ``policy_over_greedy_time``, the ratio of their mean
        exploration times.

    Raises:
        UserInputError: no modes, an unknown mode, explorer modes without ``heldout`` or
            ``unseen``, ``prior`` for a policy other than a GVN with v2 or v3 observations,
            a count out of range, or an unreadable config or weights file.
    """
    if isinstance(modes, str):
        modes = modes.split(",")
    modes = list(dict.fromkeys(m for m in modes if m))  # Each once, in the order given.
    if not modes:
        raise UserInputError(f"--modes takes {', '.join(MODES)} (and, with --heldout or "
                             "--unseen, explorer names), comma-separated.")
    for flag, value, least in (("--episodes", episodes, 1), ("--unseen", unseen, 0),
                               ("--workers", workers, 1), ("--seed-base", seed_base, 0)):
        if value < least:
            raise UserInputError(f"{flag} {value} must be a whole number >= {least}.")
    from mjexplore.explorers import CLASSIC

    explorers = sorted(set(modes) - set(MODES))
    for name in explorers:
        if name not in CLASSIC:
            raise UserInputError(f"--modes: unknown mode {name!r}: use {', '.join(MODES)} or, "
                                 f"with --heldout or --unseen, an explorer: "
                                 f"{', '.join(CLASSIC)}.")
    if explorers and not (heldout or unseen):
        raise UserInputError(f"explorer modes ({', '.join(explorers)}) need --heldout or "
                             "--unseen N (a given layout): add one, or drop them from --modes.")
    train_config = probe_config(config, weights)
    if "prior" in modes:
        from mjexplore.envs.observation import POSED

        features = train_config.env.observation.features
        if train_config.kind != "gvn" or features not in POSED:
            what = (f"a GVN with {features} observations" if train_config.kind == "gvn"
                    else f"a {train_config.kind} policy")
            raise UserInputError(f"--modes prior needs a GVN with v2 or v3 observations; "
                                 f"{weights!r} is {what}: drop prior from --modes.")
    if "policy" in modes:  # Unreadable weights or another kind: said here, not in a worker.
        from mjexplore.policies.weights import load_policy

        load_policy(weights, expected_kind=train_config.kind)

    layout_list: list[tuple[int, str | None]]
    if heldout or unseen:
        evaluation = train_config.eval
        scenes = evaluation.unseen_scenes(unseen) if unseen else evaluation.scene_list()
        layout_list = [(evaluation.seed, scene) for scene in scenes]
    else:
        layout_list = [(seed_base + i, None) for i in range(episodes)]
    jobs = [(config, weights, mode, seed, scene)
            for seed, scene in layout_list for mode in modes]
    with mp.get_context("spawn").Pool(workers) as pool:
        rows = pool.map(probe_episode, jobs, chunksize=1)
    layouts = (f"{unseen} past model selection" if unseen else
               "heldout" if heldout else f"seeds from {seed_base}")
    figures: dict = {"config": config or "stored with the weights",
                     "weights": weights, "episodes": len(layout_list), "layouts": layouts}
    for mode in modes:
        mine = [r for r in rows if r["mode"] == mode]
        for key in ("return", "exploration_time_s", "path_length_m"):
            if mine[0][key] is not None:
                figures[f"{mode}_{key}"] = round(sum(r[key] for r in mine) / len(mine), 3)
        figures[f"{mode}_explored"] = sum(r["explored"] for r in mine)
    if set(DEFAULT_MODES) <= set(modes):
        span = figures["greedy_return"] - figures["random_return"]
        figures["learned_fraction"] = (round((figures["policy_return"]
                                              - figures["random_return"]) / span, 3)
                                       if span else None)
    if {"policy", "greedy"} <= set(modes):
        figures["policy_over_greedy_time"] = round(figures["policy_exploration_time_s"]
                                                   / figures["greedy_exploration_time_s"], 3)
    return figures
