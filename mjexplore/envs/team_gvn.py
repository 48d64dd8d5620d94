"""The team's ParallelEnv with the single-robot GVN observation per robot.

Description:
    The team episode of :class:`~mjexplore.envs.team.TeamExplorationEnv` (N robots, one
    shared map, one navigator each, decisions as each robot needs one), but each agent sees
    what a single robot's GVN sees (:class:`~mjexplore.envs.exploration.ExplorationEnv` with
    ``decisions='ter'``): the padded TER of the team's shared map built from its own robot's
    pose, and its own episodic memory of its robot's last decisions, built by the same
    :class:`~mjexplore.envs.decisions.TerDecisions` (one per robot). Teammates' current
    goals come in a key of their own, ``teammate_goal_distance``, so that a GVN trained
    alone reads the rest of the observation unchanged: a shipped single-robot policy acts
    per robot on ``single_robot_observation(obs)`` (its layout given as ``observation`` and
    ``topology``, e.g. ``load_policy(path)[1]["decisions"]``'s ``config`` and
    ``topology``), ignoring its teammates but for their bodies in its costmap.

Action Space:
    ``Discrete(max_nodes)``: a TER node, as in the single-robot env. The valid ones
    (``action_mask``) are the frontier nodes that are not blacklisted, or every real node
    with ``valid_actions='all_nodes'`` (a non-frontier node is a waypoint, driven to until
    reached). An invalid action (or a decision with no valid node) sends the robot to its
    nearest reachable frontier, as the engine's fallback does.

Observation Space:
    ``Dict``: every key of the single-robot TER observation for ``observation`` (node
    features, neighbours, node mask, the raw episodic memory, ``memory_pose`` for v2 and
    v3, ``privileged`` when configured: here the team's area still to see, from the
    ground truth, for a critic only; see :mod:`mjexplore.envs.observation`), and

    * ``teammate_goal_distance`` (N_max): per node, the straight-line distance from the
      node to the nearest teammate's current goal, in metres / 20, capped at 5 (5 when no
      teammate has a goal, and for padding);
    * ``action_mask`` (N_max, int8): the valid actions.

Rewards, Starting State, Episode End:
    As :class:`~mjexplore.envs.team.TeamExplorationEnv` (one team reward: time spent
    against area seen, a completion bonus).

Arguments:
    scene, robots, config, starts, max_decisions, time_scale, gain_scale, completion: as
    :class:`~mjexplore.envs.team.TeamExplorationEnv`. observation: the TER observation's
    layout (N_max, K, memory, feature set). topology: the TER settings a policy was
    trained with (None: the episode's). valid_actions: 'frontiers' or 'all_nodes'.
    replan_period: seconds between a driving robot's decisions; None (default) decides,
    as the single robot's GVN does, when the goal is reached, seen, given up or stalls.

Version History:
    v0: first version.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np

from mjexplore.envs.decisions import TerDecisions
from mjexplore.envs.observation import ObservationConfig, privileged_features
from mjexplore.envs.team import SCALE, TeamExplorationEnv
from mjexplore.episode import EpisodeConfig
from mjexplore.scenes.scene import SceneFiles
from mjexplore.topology.pipeline import TopologyConfig

GOAL_KEY = "teammate_goal_distance"
GOAL_CAP = 5.0  # teammate_goal_distance of a node far from (or without) teammates' goals.
TEAM_KEYS = (GOAL_KEY, "action_mask")  # The keys a single-robot GVN does not read.


def single_robot_observation(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """An agent's observation as the single-robot env gives it (the team keys dropped)."""
    return {k: v for k, v in obs.items() if k not in TEAM_KEYS}


def teammate_goal_distance(positions: np.ndarray, node_mask: np.ndarray,
                           goals: list[np.ndarray]) -> np.ndarray:
    """Per node (N,), the distance from its position (``map`` frame, metres) to the nearest
    of ``goals``, in metres / 20, capped at 5; 5 for padding or without goals."""
    out = np.full(len(node_mask), GOAL_CAP, np.float32)
    real = np.asarray(node_mask) > 0
    if goals and real.any():
        g = np.asarray(goals, float).reshape(-1, 2)
        d = np.linalg.norm(positions[real, None, :2] - g[None], axis=2).min(axis=1)
        out[real] = np.minimum(d / SCALE, GOAL_CAP)
    return out


def agent_observation_space(decisions: TerDecisions) -> gym.spaces.Dict:
    """An agent's observation space: the single-robot TER observation's of ``decisions``
    and the team keys."""
    n = decisions.config.max_nodes
    return gym.spaces.Dict({
        **decisions.observation_space.spaces,
        GOAL_KEY: gym.spaces.Box(0.0, GOAL_CAP, (n,), np.float32),
        "action_mask": gym.spaces.Box(0, 1, (n,), np.int8),
    })


class TeamGvnEnv(TeamExplorationEnv):
    """See the module docstring."""

    metadata = {"name": "mjexplore_team_gvn_v0", "render_modes": []}

    def __init__(self, scene: str | SceneFiles = "train_loop", robots: int = 2,
                 observation: ObservationConfig | None = None,
                 topology: TopologyConfig | None = None, valid_actions: str = "frontiers",
                 config: EpisodeConfig | None = None, starts: list | None = None,
                 replan_period: float | None = None, max_decisions: int = 500,
                 time_scale: float = 0.01, gain_scale: float = 0.01,
                 completion: float = 1.0) -> None:
        obs_cfg = observation or ObservationConfig()
        if valid_actions not in ("frontiers", "all_nodes"):
            raise ValueError(f"valid_actions must be 'frontiers' or 'all_nodes', not "
                             f"{valid_actions!r}")
        super().__init__(scene, robots, obs_cfg.max_nodes, config, starts, replan_period,
                         max_decisions, time_scale, gain_scale, completion)
        # As the single-robot env: the episode's TER has the observation's sizes.
        topo = self.config.topology
        self.config = dataclasses.replace(self.config, topology=dataclasses.replace(
            topo, ter=dataclasses.replace(topo.ter, max_nodes=obs_cfg.max_nodes,
                                          max_neighbours=obs_cfg.max_neighbours)))
        self.observation_config = obs_cfg
        self.decisions = [TerDecisions(obs_cfg, valid_actions, topology)
                          for _ in range(robots)]
        space = agent_observation_space(self.decisions[0])
        self._observation_spaces = {a: space for a in self.possible_agents}

    def reset(self, seed: int | None = None, options: dict | None = None):
        for d in self.decisions:
            d.reset()
        return super().reset(seed, options)

    def _choose(self, index: int, action: int) -> None:
        d = self.decisions[index]
        if d.padded is None or not 0 <= action < len(d.mask) or not d.mask[action]:
            return  # Invalid: the explorer takes the nearest frontier.
        choice = d.act(action)  # Remembered in this robot's memory.
        assert choice is not None  # A masked-in action is a real node.
        goal, waypoint = choice
        explorer = self.explorers[index]
        explorer.pending, explorer.pending_waypoint = goal, waypoint

    def _observe(self) -> dict[str, dict[str, np.ndarray]]:
        ep = self.episode
        assert ep is not None
        privileged = None
        if self.observation_config.privileged:
            privileged = privileged_features(ep.counter.count, ep.counter.total,
                                             ep.config.target_ratio,
                                             ep.mapper.grid.resolution ** 2)
        out: dict[str, dict[str, np.ndarray]] = {}
        for a in ep.agents:
            name = self.possible_agents[a.index]
            if name not in self.agents:
                continue
            d = self.decisions[a.index]
            state = a.decision_state()
            d.prepare(state)  # The TER of the shared map from this robot's pose.
            obs = d.observation()
            if privileged is not None:
                obs["privileged"] = privileged.copy()
            view = state.extras["team"]
            goals = [view.goals[j] for j in view.teammates if view.goals[j] is not None]
            if d.padded is not None:
                obs[GOAL_KEY] = teammate_goal_distance(d.padded.node_positions,
                                                       d.padded.node_mask, goals)
            else:
                obs[GOAL_KEY] = np.full(self.k, GOAL_CAP, np.float32)
            obs["action_mask"] = d.mask.astype(np.int8)
            out[name] = obs
        return out


def parallel_env(**kwargs) -> TeamGvnEnv:
    """The env (PettingZoo's constructor convention)."""
    return TeamGvnEnv(**kwargs)


class TeamDecisionEnv(gym.Env):
    """A team's decisions one at a time, as a Gymnasium env: one policy decides for every
    robot (parameter sharing), so that SB3's (Maskable)PPO trains a team with the
    single-robot recipe's machinery (``mjexplore train`` with ``env.robots`` > 1).

    Each reset draws a scene as the single-robot env does (:func:`~mjexplore.envs.
    exploration.draw_scene`) and runs a :class:`TeamGvnEnv` on it. A step is one deciding
    robot's choice, its observation that robot's (:func:`agent_observation_space`); robots
    that decide at the same instant decide in turn (reward 0 between them, the world
    standing still), and once every deciding robot has chosen the team runs on to the next
    decision, the step's reward the team's (``env.reward``'s ``time`` terms: -time_scale per
    simulated second, time_scale x gain_s_per_m2 per m^2 seen, time_scale x completion_s
    on finishing). The episode ends as :class:`TeamGvnEnv`'s.

    Args:
        config: The env's settings (``robots`` > 1, ``decisions`` 'ter').
    """

    metadata = {"render_modes": []}
    # Only in a worker process: its threads per library (learning.vec_envs.worker_env).
    worker_threads: dict[str, int]

    def __init__(self, config) -> None:
        from mjexplore.envs.exploration import EnvConfig

        if not isinstance(config, EnvConfig) or config.robots < 2:
            raise ValueError("TeamDecisionEnv needs an EnvConfig with robots >= 2")
        self.config = config
        decisions = TerDecisions(config.observation, config.valid_actions)
        self.spaces = agent_observation_space(decisions)
        self.observation_space = self.spaces
        self.action_space = decisions.action_space
        self.team: TeamGvnEnv | None = None
        self._scene_cache: dict[str, SceneFiles] = {}
        self._obs: dict[str, dict[str, np.ndarray]] = {}
        self._queue: list[str] = []  # The agents still to decide at this instant.
        self._actions: dict[str, int] = {}
        self._last: dict[str, np.ndarray] | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        from mjexplore.envs.exploration import draw_scene

        super().reset(seed=seed)
        cfg = self.config
        reward = cfg.reward
        rng = self.np_random
        self.team = TeamGvnEnv(draw_scene(cfg, rng, self._scene_cache), cfg.robots,
                               observation=cfg.observation, valid_actions=cfg.valid_actions,
                               config=cfg.episode, max_decisions=cfg.max_decisions,
                               time_scale=reward.time_scale,
                               gain_scale=reward.time_scale * reward.gain_s_per_m2,
                               completion=reward.time_scale * reward.completion_s)
        obs, infos = self.team.reset(seed=int(rng.integers(2**31 - 1)))
        self._take(obs, infos)
        return self._current(), self._info()

    def _take(self, obs, infos) -> None:
        self._obs = obs
        self._queue = [a for a in obs if infos.get(a, {}).get("deciding")]
        self._actions = {}

    def _current(self) -> dict[str, np.ndarray]:
        if self._queue:
            self._last = self._obs[self._queue[0]]
        elif self._obs:
            self._last = next(iter(self._obs.values()))
        if self._last is None:  # Ended before any decision: a blank observation.
            blank = self.spaces.sample()
            self._last = {k: np.zeros_like(v) for k, v in blank.items()}
        return self._last

    def _info(self) -> dict:
        team = self.team
        assert team is not None and team.episode is not None
        ep = team.episode
        return {"exploration_ratio": float(ep.ratio), "sim_time": float(ep.time),
                "end_reason": ep.end_reason,
                "robot": self._queue[0] if self._queue else None}

    def action_masks(self) -> np.ndarray:
        """Valid actions of the deciding robot (bool), for sb3-contrib's MaskablePPO."""
        mask = self._current()["action_mask"].astype(bool)
        return mask if mask.any() else np.ones_like(mask)  # Invalid: its nearest frontier.

    def step(self, action):
        team = self.team
        if team is None:
            raise RuntimeError("call reset() before step()")
        if self._queue:
            self._actions[self._queue.pop(0)] = int(action)
        if self._queue:  # Another robot decides at the same instant.
            return self._current(), 0.0, False, False, self._info()
        obs, rewards, terms, truncs, infos = team.step(self._actions)
        reward = float(next(iter(rewards.values()), 0.0))
        terminated = any(terms.values())
        truncated = any(truncs.values()) and not terminated
        self._take(obs, infos)
        info = self._info()
        if terminated or truncated:
            assert team.episode is not None
            info["episode_metrics"] = team.episode.result().metrics
        return self._current(), reward, terminated, truncated, info


__all__ = ["GOAL_KEY", "TEAM_KEYS", "TeamDecisionEnv", "TeamGvnEnv", "agent_observation_space",
           "parallel_env", "single_robot_observation", "teammate_goal_distance"]
