"""Team exploration as a PettingZoo ``ParallelEnv``: one agent per robot.

Description:
    N robots explore one scene with one shared map (:class:`~mjexplore.episode.engine.
    Episode` of a team: physics or kinematic world, one navigator per robot, teammates as
    obstacles). An agent chooses its robot's next goal among the frontiers it can reach;
    the world runs until some robot needs a decision (its goal was reached, vanished or
    given up, or ``replan_period`` passed), and each step returns every agent's view.
    Decisions come as each robot needs one: the agents with a decision due are flagged
    ``info["deciding"]``, and only their actions are used (the others' are ignored and
    their robots drive on).

Action Space:
    ``Discrete(max_candidates)``: the index of a candidate frontier (nearest first by the
    robot's own path cost). Invalid indices are masked out (``action_mask``); an invalid
    action sends the robot to its nearest candidate.

Observation Space:
    ``Dict``: ``observation``, a ``Box(max_candidates, 8)`` of per-candidate features
    (zeros for padding): path cost from the robot and from its nearest teammate (metres /
    20, capped at 5), straight-line distance (/ 20), frontier size (cells / 100, capped at
    5), whether a teammate's current goal lies within 1.5 m, the candidate's offset from
    the robot (dx, dy / 20) and 1 for a real candidate; ``action_mask``, an int8
    ``Box(max_candidates)`` of the valid actions; ``team``, a ``Box(4)``: the team's
    exploration ratio, the time (/ max_time), the distance to the nearest teammate
    (/ 20, capped at 5) and whether the robot has a goal now.

Rewards:
    Shared by the team (cooperative): per step, ``-time_scale * dt`` (the simulated
    seconds the step took) ``+ gain_scale * dA`` (square metres of the observable ground
    truth first seen during it), and ``completion`` when the team reaches the target ratio.

Starting State:
    Robot 0 at the scene's (jittered) start, the others drawn 1-3 m around it from the
    seed (:func:`~mjexplore.scenes.team.draw_starts`), or ``starts``.

Episode End:
    The Gymnasium env's rules (``TERMINAL_REASONS``), for every agent: terminated when the
    team's map reaches the target ratio, no robot finds a reachable frontier, a robot is
    lost or tips over; truncated at the time cap, after ``max_decisions`` steps, or when the
    episode ends otherwise (lingering, physics fault).

Arguments:
    scene: Scene name or path. robots: team size. max_candidates: K. config: the episode's
    settings (default: kinematic world, 300 s cap). replan_period: seconds between a
    robot's decisions while it drives. max_decisions: steps before truncation.

Version History:
    v0: first version.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
from pettingzoo import ParallelEnv

from mjexplore.envs.exploration import TERMINAL_REASONS
from mjexplore.episode import EpisodeConfig
from mjexplore.episode.engine import Episode
from mjexplore.episode.explorer import ExplorationState
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import SceneFiles
from mjexplore.sim.simulator import SimConfig

FEATURES = 8
SCALE = 20.0  # Metres per unit of the distance features.


class ChosenGoal:
    """A robot's explorer in the env: the goal its agent chose (consumed once), else the
    nearest frontier. ``pending_waypoint`` marks a chosen goal that is a waypoint (a TER
    node that is not a frontier: driven to until reached, see
    :mod:`mjexplore.envs.team_gvn`)."""

    name = "agent"

    def __init__(self, replan_period: float | None) -> None:
        self.pending: np.ndarray | None = None
        self.pending_waypoint = False
        self.waypoint = False  # Read by the engine for the goal just selected.
        self.replan_period = replan_period
        self._nearest = NearestFrontier()

    def reset(self, rng: np.random.Generator) -> None:
        self.pending = None
        self.pending_waypoint = self.waypoint = False

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        goal, self.pending = self.pending, None
        self.waypoint, self.pending_waypoint = goal is not None and self.pending_waypoint, False
        return goal if goal is not None else self._nearest.select_goal(state)


class TeamExplorationEnv(ParallelEnv):
    """See the module docstring."""

    metadata = {"name": "mjexplore_team_v0", "render_modes": []}

    def __init__(self, scene: str | SceneFiles = "train_loop", robots: int = 2,
                 max_candidates: int = 8, config: EpisodeConfig | None = None,
                 starts: list | None = None, replan_period: float | None = 10.0,
                 max_decisions: int = 500, time_scale: float = 0.01,
                 gain_scale: float = 0.01, completion: float = 1.0) -> None:
        self.scene = scene if isinstance(scene, SceneFiles) else resolve_scene(scene)
        self.n = robots
        self.k = max_candidates
        self.config = config or EpisodeConfig(sim=SimConfig(dynamics="kinematic"),
                                              max_time=300.0)
        self.starts = starts
        self.replan_period = replan_period
        self.max_decisions = max_decisions
        self.time_scale, self.gain_scale, self.completion = time_scale, gain_scale, completion
        self.possible_agents = [f"robot_{i}" for i in range(robots)]
        self.agents: list[str] = []
        self.episode: Episode | None = None
        self._seed: int | None = None
        self._candidates: list[np.ndarray] = [np.zeros((0, 2)) for _ in range(robots)]
        # One space object per agent, returned every time (PettingZoo's API test checks).
        self._observation_spaces = {a: gym.spaces.Dict({
            "observation": gym.spaces.Box(-5.0, 5.0, (self.k, FEATURES), np.float32),
            "action_mask": gym.spaces.Box(0, 1, (self.k,), np.int8),
            "team": gym.spaces.Box(0.0, 5.0, (4,), np.float32),
        }) for a in self.possible_agents}
        self._action_spaces = {a: gym.spaces.Discrete(self.k) for a in self.possible_agents}

    def observation_space(self, agent: str) -> gym.spaces.Dict:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> gym.spaces.Discrete:
        return self._action_spaces[agent]

    # ------------------------------------------------------------------ episode

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._seed = seed
        elif self._seed is None:
            self._seed = 0
        else:
            self._seed += 1
        self.explorers = [ChosenGoal(self.replan_period) for _ in range(self.n)]
        self.episode = Episode(self.scene, self.explorers, self._seed, self.config,
                               starts=self.starts)
        self.agents = list(self.possible_agents)
        self.steps = 0
        self._known = self.episode.counter.count
        deciding = self._advance()
        return self._observe(), self._infos(deciding)

    def _advance(self) -> set[int]:
        """Runs the team until a robot needs a decision or the episode ends; the robots
        whose decision is due."""
        ep = self.episode
        assert ep is not None
        while not ep._check_end():
            due = {a.index for a in ep.agents if a.active and a.decision_due()}
            if due:
                return due
            if not ep.step():
                break
        return set()

    def step(self, actions: dict[str, int]):
        ep = self.episode
        assert ep is not None
        t0 = ep.time
        for a in ep.agents:
            name = self.possible_agents[a.index]
            if name in actions and a.active and a._decision_due:
                self._choose(a.index, int(actions[name]))
        if not ep._check_end():
            ep.step()  # The decisions, with the chosen goals, and one control period.
        deciding = self._advance()
        self.steps += 1
        known = ep.counter.count
        cell = ep.mapper.grid.resolution ** 2
        reward = (-self.time_scale * (ep.time - t0) +
                  self.gain_scale * (known - self._known) * cell)
        self._known = known
        end = ep.end_reason if ep.end_reason is not None or ep._check_end() else None
        terminated = end in TERMINAL_REASONS  # The Gymnasium env's rules.
        truncated = end is not None and not terminated or self.steps >= self.max_decisions
        if end == "explored":
            reward += self.completion
        obs, infos = self._observe(), self._infos(deciding)
        agents = list(self.agents)
        rewards = dict.fromkeys(agents, float(reward))
        terms = dict.fromkeys(agents, bool(terminated))
        truncs = dict.fromkeys(agents, bool(truncated and not terminated))
        if terminated or truncated:
            self.agents = []
        return obs, rewards, terms, truncs, infos

    def _choose(self, index: int, action: int) -> None:
        """Hands robot ``index``'s chosen candidate to its explorer (an invalid index: its
        nearest candidate)."""
        cands = self._candidates[index]
        if len(cands):
            self.explorers[index].pending = cands[action if 0 <= action < len(cands) else 0]

    # ------------------------------------------------------------------ views

    def _infos(self, deciding: set[int]) -> dict[str, dict[str, Any]]:
        ep = self.episode
        assert ep is not None
        return {name: {"deciding": i in deciding, "time": round(ep.time, 3),
                       "ratio": round(ep.ratio, 5), "end_reason": ep.end_reason}
                for i, name in enumerate(self.possible_agents) if name in self.agents}

    def _observe(self) -> dict[str, dict[str, np.ndarray]]:
        ep = self.episode
        assert ep is not None
        out: dict[str, dict[str, np.ndarray]] = {}
        poses = ep.world.poses()
        for a in ep.agents:
            name = self.possible_agents[a.index]
            if name not in self.agents:
                continue
            feats = np.zeros((self.k, FEATURES), np.float32)
            mask = np.zeros(self.k, np.int8)
            state = a.decision_state()
            cands = np.zeros((0, 2))
            if state.frontiers:
                d_me = state.frontier_distances()
                order = [j for j in np.argsort(d_me) if np.isfinite(d_me[j])][:self.k]
                cands = np.array([state.frontiers[j].goal for j in order]).reshape(-1, 2)
                others = [b for b in ep.agents if b.index != a.index]
                d_team = np.full(len(state.frontiers), np.inf)
                for b in others:
                    view = dataclasses.replace(state, pose=poses[b.index], costmap=b._costmap)
                    d_team = np.minimum(d_team, view.frontier_distances())
                goals = np.array([b.goal for b in others if b.goal is not None]).reshape(-1, 2)
                for row, j in enumerate(order):
                    f = state.frontiers[j]
                    dx, dy = f.goal - poses[a.index][:2]
                    claimed = len(goals) and np.hypot(*(goals - f.goal).T).min() <= 1.5
                    feats[row] = (min(d_me[j] / SCALE, 5.0), min(d_team[j] / SCALE, 5.0),
                                  min(np.hypot(dx, dy) / SCALE, 5.0), min(f.size / 100, 5.0),
                                  float(claimed), np.clip(dx / SCALE, -5, 5),
                                  np.clip(dy / SCALE, -5, 5), 1.0)
                    mask[row] = 1
            self._candidates[a.index] = cands
            d = np.hypot(*(poses[:, :2] - poses[a.index, :2]).T)
            d[a.index] = np.inf
            team = np.array([ep.ratio, min(ep.time / self.config.max_time, 1.0),
                             min(d.min() / SCALE, 5.0) if self.n > 1 else 5.0,
                             float(a.goal is not None)], np.float32)
            out[name] = {"observation": feats, "action_mask": mask, "team": team}
        return out

    def close(self) -> None:
        self.episode = None


def parallel_env(**kwargs) -> TeamExplorationEnv:
    """The env (PettingZoo's constructor convention)."""
    return TeamExplorationEnv(**kwargs)


__all__ = ["ChosenGoal", "TeamExplorationEnv", "parallel_env"]
