"""A warm start for PPO: the policy imitates the ground-truth oracle (behaviour cloning).

The oracle (:mod:`mjexplore.explorers.oracle`) knows the true map and plans a near-optimal
coverage tour; :meth:`~mjexplore.explorers.oracle.OracleExplorer.expert_choice` says which
of the valid TER nodes it would go to next. Episodes of the training env are driven by
those choices, every decision's observation, mask and expert action is kept, and the
policy's actor is fitted to the expert actions by cross-entropy over the valid actions
(the critic is left to PPO). Learned explorers that beat classic ones start so (ARiADNE's
successors and most imitation-then-RL recipes): PPO from a uniform policy spends most of a
small budget finding what a planner already knows.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImitationConfig:
    """Behaviour cloning before PPO.

    Attributes:
        episodes: Expert episodes to collect (0: no warm start).
        epochs: Passes over the collected decisions.
        batch_size: Decisions per gradient step.
        learning_rate: Adam's step size for the cloning.
        seed: Seed of the expert episodes' layouts and starts (disjoint from PPO's when it
            differs from the run's seed).
    """

    episodes: int = 0
    epochs: int = 8
    batch_size: int = 64
    learning_rate: float = 1e-3
    seed: int = 1_000_003

    def __post_init__(self) -> None:
        if self.episodes < 0 or self.epochs < 1 or self.batch_size < 1 or \
                self.learning_rate <= 0:
            raise ValueError("imitation: episodes must be >= 0, epochs and batch_size >= 1, "
                             "learning_rate > 0")


def collect_expert_decisions(env_config, episodes: int, seed: int
                             ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict]:
    """Runs ``episodes`` training-env episodes with the oracle choosing every node.

    Returns:
        (observations stacked per key, (n, A) bool action masks, (n,) expert actions,
        stats: decisions, episodes explored, mean exploration time in simulated seconds).
    """
    from mjexplore.envs import ExplorationEnv
    from mjexplore.explorers import make_explorer

    env = ExplorationEnv(env_config)
    oracle = make_explorer("oracle")
    observations: dict[str, list[np.ndarray]] = {}
    masks, actions, times, explored = [], [], [], 0
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        oracle.reset(np.random.default_rng(seed + k))
        while True:
            mask = env.action_masks()
            action = oracle.expert_choice(env.episode.decision_state(),
                                          env.decisions.action_positions(), mask)
            if action < 0:
                break
            for key, value in obs.items():
                observations.setdefault(key, []).append(np.asarray(value).copy())
            masks.append(mask)
            actions.append(action)
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                explored += info["end_reason"] == "explored"
                times.append(info["sim_time"])
                break
    env.close()
    stats = {"decisions": len(actions), "episodes": episodes, "explored": explored,
             "mean_exploration_time_s": float(np.mean(times)) if times else None}
    return ({k: np.stack(v) for k, v in observations.items()}, np.array(masks, bool),
            np.array(actions, np.int64), stats)


def clone(policy, observations: dict[str, np.ndarray], masks: np.ndarray,
          actions: np.ndarray, config: ImitationConfig, seed: int = 0) -> dict[str, Any]:
    """Fits the policy's actor to the expert actions (masked cross-entropy, Adam).

    Returns:
        The final epoch's mean loss and the share of decisions whose most likely valid
        action is the expert's.
    """
    import torch

    rng = np.random.default_rng(seed)
    params = [p for name, p in policy.named_parameters() if "value_net" not in name and
              "vf_features_extractor" not in name and "critic" not in name]
    optimizer = torch.optim.Adam(params, lr=config.learning_rate)
    n = len(actions)
    policy.set_training_mode(True)
    loss_sum = agree = 0.0
    for _ in range(config.epochs):
        loss_sum = agree = 0.0
        order = rng.permutation(n)
        for start in range(0, n, config.batch_size):
            idx = order[start:start + config.batch_size]
            obs = {k: torch.as_tensor(v[idx]) for k, v in observations.items()}
            dist = policy.get_distribution(obs, action_masks=masks[idx])
            target = torch.as_tensor(actions[idx])
            loss = -dist.log_prob(target).mean()
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 0.5)
            optimizer.step()
            loss_sum += float(loss.detach()) * len(idx)
            agree += float((dist.distribution.probs.argmax(-1) == target).sum())
    policy.set_training_mode(False)
    return {"loss": loss_sum / max(n, 1), "agreement": agree / max(n, 1)}
