"""Independent PPO for the team env: one small policy per robot, trained on its own
decisions (Schulman et al.'s clipped objective, GAE), the simplest multi-agent baseline.

Each agent's policy scores its candidate frontiers with a shared MLP over each
candidate's features and the team features (one logit per candidate, masked), and a
value head on the mean of the candidate embeddings. Only the decisions an agent actually
made (``info["deciding"]``) enter its rollout; rewards between its decisions are summed
into its last one. MAPPO (a centralised critic) is left for later; this is the smoke
baseline that shows the env trains.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn


@dataclasses.dataclass(frozen=True, kw_only=True)
class TeamPPOConfig:
    """Independent PPO settings.

    Attributes:
        steps: Env steps to collect in all.
        rollout: Env steps per update.
        epochs: Passes over each rollout.
        lr: Adam's learning rate.
        gamma: Discount per decision.
        lam: GAE's lambda.
        clip: PPO's clip range.
        entropy: Entropy bonus weight.
        hidden: Width of the MLP.
        seed: Seed of torch, numpy and the env.
    """

    steps: int = 256
    rollout: int = 64
    epochs: int = 4
    lr: float = 3e-4
    gamma: float = 0.99
    lam: float = 0.95
    clip: float = 0.2
    entropy: float = 0.01
    hidden: int = 64
    seed: int = 0


class CandidatePolicy(nn.Module):
    """Per-candidate logits and a value from candidate and team features."""

    def __init__(self, features: int, team: int, hidden: int = 64) -> None:
        super().__init__()
        self.embed = nn.Sequential(nn.Linear(features + team, hidden), nn.Tanh(),
                                   nn.Linear(hidden, hidden), nn.Tanh())
        self.logit = nn.Linear(hidden, 1)
        self.value = nn.Linear(hidden, 1)

    def forward(self, cand: torch.Tensor, team: torch.Tensor, mask: torch.Tensor,
                ) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([cand, team[:, None, :].expand(-1, cand.shape[1], -1)], dim=-1)
        h = self.embed(x)
        logits = self.logit(h).squeeze(-1)
        # No valid candidate: a uniform choice (the env sends the robot to the nearest).
        any_valid = mask.any(dim=1, keepdim=True)
        logits = torch.where(mask | ~any_valid, logits, torch.full_like(logits, -1e9))
        weights = mask.float() + (~any_valid).float()
        pooled = (h * weights[..., None]).sum(1) / weights.sum(1, keepdim=True)
        return logits, self.value(pooled).squeeze(-1)


def _tensors(obs: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return (torch.as_tensor(obs["observation"], dtype=torch.float32)[None],
            torch.as_tensor(obs["team"], dtype=torch.float32)[None],
            torch.as_tensor(obs["action_mask"], dtype=torch.bool)[None])


def train_independent_ppo(env, config: TeamPPOConfig | None = None,
                          ) -> tuple[dict[str, CandidatePolicy], list[dict[str, float]]]:
    """Trains one policy per agent of ``env`` (a :class:`~mjexplore.envs.team.
    TeamExplorationEnv`); returns the policies and a log line per update (mean episode
    return so far, losses)."""
    cfg = config or TeamPPOConfig()
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    agents = list(env.possible_agents)
    space = env.observation_space(agents[0])
    features = space["observation"].shape[1]
    team = space["team"].shape[0]
    policies = {a: CandidatePolicy(features, team, cfg.hidden) for a in agents}
    optims = {a: torch.optim.Adam(policies[a].parameters(), lr=cfg.lr) for a in agents}
    obs, infos = env.reset(seed=cfg.seed)
    buffers: dict[str, list[dict]] = {a: [] for a in agents}
    returns: list[float] = []
    episode_return = 0.0
    log: list[dict[str, float]] = []
    done_steps = 0
    while done_steps < cfg.steps:
        for _ in range(cfg.rollout):
            actions = {}
            for a in env.agents:
                if not infos[a]["deciding"]:
                    actions[a] = 0
                    continue
                cand, tm, mask = _tensors(obs[a])
                with torch.no_grad():
                    logits, value = policies[a](cand, tm, mask)
                dist = torch.distributions.Categorical(logits=logits)
                act = dist.sample()
                actions[a] = int(act)
                buffers[a].append({"obs": (cand, tm, mask), "action": act,
                                   "logp": dist.log_prob(act), "value": value,
                                   "reward": 0.0, "done": False})
            obs, rewards, terms, truncs, infos = env.step(actions)
            done_steps += 1
            r = float(np.mean(list(rewards.values()))) if rewards else 0.0
            episode_return += r
            ended = bool(terms) and (all(terms.values()) or all(truncs.values()) or
                                     not env.agents)
            for a in agents:
                if buffers[a]:
                    buffers[a][-1]["reward"] += rewards.get(a, 0.0)
                    buffers[a][-1]["done"] |= ended and terms.get(a, False)
            if ended or not env.agents:
                returns.append(episode_return)
                episode_return = 0.0
                obs, infos = env.reset(seed=int(rng.integers(1 << 30)))
        log.append(_update(policies, optims, buffers, cfg) | {
            "steps": float(done_steps),
            "mean_return": float(np.mean(returns)) if returns else float("nan")})
        buffers = {a: [] for a in agents}
    return policies, log


def _update(policies, optims, buffers, cfg: TeamPPOConfig) -> dict[str, float]:
    stats = {"policy_loss": 0.0, "value_loss": 0.0, "entropy": 0.0}
    updated = 0
    for a, buf in buffers.items():
        if len(buf) < 2:
            continue
        values = torch.stack([b["value"] for b in buf]).squeeze(-1)
        rewards = torch.tensor([b["reward"] for b in buf])
        dones = torch.tensor([b["done"] for b in buf], dtype=torch.float32)
        adv = torch.zeros(len(buf))
        last: float | torch.Tensor = 0.0
        for t in reversed(range(len(buf))):
            nxt = values[t + 1] if t + 1 < len(buf) else torch.tensor(0.0)
            delta = rewards[t] + cfg.gamma * nxt * (1 - dones[t]) - values[t]
            last = delta + cfg.gamma * cfg.lam * (1 - dones[t]) * last
            adv[t] = last
        target = adv + values
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        cand = torch.cat([b["obs"][0] for b in buf])
        tm = torch.cat([b["obs"][1] for b in buf])
        mask = torch.cat([b["obs"][2] for b in buf])
        actions = torch.stack([b["action"] for b in buf]).squeeze(-1)
        old_logp = torch.stack([b["logp"] for b in buf]).squeeze(-1)
        for _ in range(cfg.epochs):
            logits, value = policies[a](cand, tm, mask)
            dist = torch.distributions.Categorical(logits=logits)
            ratio = torch.exp(dist.log_prob(actions) - old_logp)
            policy_loss = -torch.min(ratio * adv,
                                     ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * adv).mean()
            value_loss = ((value - target) ** 2).mean()
            entropy = dist.entropy().mean()
            loss = policy_loss + 0.5 * value_loss - cfg.entropy * entropy
            optims[a].zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(policies[a].parameters(), 0.5)
            optims[a].step()
        stats["policy_loss"] += float(policy_loss.detach())
        stats["value_loss"] += float(value_loss.detach())
        stats["entropy"] += float(entropy.detach())
        updated += 1
    return {k: v / max(updated, 1) for k, v in stats.items()} | {"agents_updated": updated}


__all__ = ["CandidatePolicy", "TeamPPOConfig", "train_independent_ppo"]
