"""Held-out evaluation of a policy during and after training: episodes on the held-out
scenes (:func:`evaluate_policy_episodes`, in worker processes), the score model selection
maximises (:func:`eval_score`), the evaluation schedule of a run folder (``eval.csv``) and
the nearest-node rule, the baseline a learned GVN has to beat (:class:`NearestNodeRule`)."""

from __future__ import annotations

import csv
import dataclasses
import multiprocessing
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mjexplore.envs.exploration import EnvConfig, ExplorationEnv
from mjexplore.envs.team_gvn import TeamDecisionEnv
from mjexplore.episode.workers import init_episode_worker
from mjexplore.errors import UserInputError
from mjexplore.learning.policy_network import fresh_policy
from mjexplore.learning.train_config import TrainConfig
from mjexplore.policies.weights import read_policy_weights


def heldout_env(config: TrainConfig, scene: str) -> ExplorationEnv:
    """The training env on one held-out scene (of ``config.eval.scene_list()``) with the
    evaluation's episode settings, one robot; reset it with ``seed=config.eval.seed``."""
    return ExplorationEnv(_heldout_config(config, scene))


def _heldout_config(config: TrainConfig, scene: str) -> EnvConfig:
    return dataclasses.replace(config.env, scenes=(scene,), procedural=None,
                               episode=config.eval.episode)


def evaluate_policy_episodes(policy, config: TrainConfig, scenes: tuple[str, ...] | None = None,
                             workers: int = 1) -> list[dict[str, Any]]:
    """Runs the policy deterministically on the held-out scenes (or ``scenes``, with the
    evaluation's episode settings); their episode metrics, in the scenes' order.

    Args:
        policy: An SB3 policy of ``config`` (on any device) or any object with SB3's
            ``predict(obs, deterministic, action_masks)``.
        config: The run's settings.
        scenes: Scenes to evaluate instead of the held-out ones.
        workers: Processes that run the episodes (one scene each at a time); a network
            runs there on the CPU with one thread, so the results equal one process's.
    """
    scenes = config.eval.scene_list() if scenes is None else tuple(scenes)
    if workers <= 1 or len(scenes) <= 1:
        return [heldout_episode(policy, config, scene) for scene in scenes]
    if isinstance(policy, torch.nn.Module):  # Its weights: rebuilt on the CPU there.
        portable = {k: v.detach().cpu() for k, v in policy.state_dict().items()}
    else:
        portable = policy
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(min(workers, len(scenes)), initializer=_eval_worker_init,
                  initargs=(config, portable)) as pool:
        return pool.map(_eval_worker_episode, scenes, chunksize=1)


def heldout_episode(policy, config: TrainConfig, scene: str,
                    env: ExplorationEnv | TeamDecisionEnv | None = None) -> dict[str, Any]:
    """One episode of ``policy`` (SB3's ``predict``, deterministic, with the action mask) on
    a held-out ``scene`` with the evaluation's settings, in this process: the scene and the
    episode's metrics (simulated time). ``env``: ``heldout_env(config, scene)`` made already
    (default: made here; a team's :class:`~mjexplore.envs.team_gvn.TeamDecisionEnv` when
    the run trains a team), for a policy that reads more of the episode than its
    observation."""
    if env is None:  # A team policy is selected on team episodes.
        env = TeamDecisionEnv(_heldout_config(config, scene)) if config.env.robots > 1 \
            else heldout_env(config, scene)
    obs, _ = env.reset(seed=config.eval.seed)
    while True:
        action, _ = policy.predict(obs, deterministic=True, action_masks=env.action_masks())
        obs, _, terminated, truncated, info = env.step(int(action))
        if terminated or truncated:
            return {"scene": scene, **info["episode_metrics"]}


_EVAL_WORKER: dict[str, Any] = {}


def _eval_worker_init(config: TrainConfig, portable) -> None:
    # A pool whose initializer raises starts new workers for ever: a failure here is kept
    # and raised by each task instead, and so reaches the parent with its message.
    try:
        init_episode_worker()
        policy = portable
        if isinstance(portable, dict):
            policy = fresh_policy(config)
            policy.load_state_dict(portable)
            policy.set_training_mode(False)
    except Exception as exc:  # noqa: BLE001 - re-raised by _eval_worker_episode
        _EVAL_WORKER.update(error=exc)
        return
    _EVAL_WORKER.update(config=config, policy=policy)


def _eval_worker_episode(scene: str) -> dict[str, Any]:
    if "error" in _EVAL_WORKER:
        raise _EVAL_WORKER["error"]
    return heldout_episode(_EVAL_WORKER["policy"], _EVAL_WORKER["config"], scene)


class NearestNodeRule:
    """The nearest-node rule as a policy for :func:`evaluate_policy_episodes`: the valid
    node nearest along the known map (the greedy choice of
    :func:`~mjexplore.policies.gvn.path_prior`; v2 or v3 observations), the baseline a
    learned GVN has to beat on the held-out layouts.

    Args:
        pocket_m: v3: count each node this many metres farther per unit of its pocket
            probability (a v3 actor's prior without the network's residual); 0: the plain
            nearest-node rule.
    """

    def __init__(self, pocket_m: float = 0.0) -> None:
        self.pocket_m = pocket_m

    def predict(self, obs: dict[str, np.ndarray], deterministic: bool = True,
                action_masks: np.ndarray | None = None) -> tuple[int, None]:
        from mjexplore.policies.gvn import path_prior

        features = torch.as_tensor(obs["node_features"]).reshape(len(obs["node_mask"]), -1)
        logits = path_prior(features, 1.0, self.pocket_m).numpy()
        if action_masks is not None:
            logits = np.where(action_masks, logits, -np.inf)
        return int(np.argmax(logits)), None


def eval_score(results: list[dict[str, Any]]) -> float:
    """How good a held-out evaluation is: mean coverage first, then mean speed. An explored
    episode counts as full coverage: what it saw past the target ratio (the last scan's
    overshoot) says nothing of the policy."""
    coverage = [1.0 if r["end_reason"] == "explored" else r["exploration_ratio"]
                for r in results]
    return (float(np.mean(coverage)) * 1e4
            - float(np.mean([r["exploration_time_s"] for r in results])))


def best_score(path: Path) -> float | None:
    """The evaluation score of the weights kept as best so far (None if there are none)."""
    if not path.is_file():
        return None
    try:
        return eval_score(read_policy_weights(path)[1]["provenance"]["eval"])
    except (UserInputError, KeyError, TypeError):
        return None  # Unreadable: the next evaluation replaces it.


def last_evaluation(out: Path) -> int | None:
    """The decisions at the run's last held-out evaluation (``eval.csv``), None before any."""
    path = out / "eval.csv"
    if not path.is_file():
        return None
    with open(path) as f:
        steps = [int(row["steps"]) for row in csv.DictReader(f)]
    return max(steps, default=None)


def next_evaluation(every: int, last: int | None) -> int:
    """The decisions at which the next held-out evaluation is due: the first multiple of
    ``every`` past the last evaluation (``last``; None: none yet), so that a run evaluates at
    the same counts however often it is resumed; one a resume skipped is due at once."""
    if every <= 0:
        return 0
    return ((last or 0) // every + 1) * every
