"""The exploration decision process as a Gymnasium environment: one TER node per step."""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from mjexplore.envs.decisions import GridConfig, GridDecisions, TerDecisions
from mjexplore.envs.observation import ObservationConfig, privileged_features
from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.explorer import ExplorationState
from mjexplore.errors import UserInputError
from mjexplore.mapping.metrics import trinary
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import SceneFiles, load_scene_files

VALID_ACTIONS = ("frontiers", "all_nodes")
DECISIONS = ("ter", "grid")
TERMINAL_REASONS = ("explored", "no_frontiers", "lost", "tipped_over")
TRAIN_FAMILIES = ("office", "maze", "loop", "corridor", "rooms", "loop+rooms",
                  "corridor+rooms", "maze+loop")


REWARD_KINDS = ("time", "paper")
# Ends short of the target that the time reward charges for: the map is left unfinished.
SHORT_ENDS = ("no_frontiers", "lost", "lingering", "tipped_over", "time_limit",
              "physics_fault")


@dataclasses.dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """The reward per decision step: 'time' (default) or 'paper'.

    **time** measures what the evaluation measures, the time to explore. In seconds'
    worth, scaled by ``time_scale``:

    r_t = time_scale * (-dt - decision_s + gain_s_per_m2 dG_info
                        + completion_s [explored] - shortfall_s u [ended short])

    with dt the simulated seconds the step took (the drive to the chosen node), dG_info the
    area of the observable ground truth first seen during it (m^2), and u = max(0, 1 -
    ratio / target) the share of the map left unexplored when the episode ends short of
    the target (``no_frontiers``, ``lost``, ``lingering``, ``tipped_over``, ``time_limit``,
    ``physics_fault``; not at ``decision_limit``, an artificial cut PPO bootstraps over).
    The undiscounted return is -time_scale (T + decision_s N - gain_s_per_m2 G + ...): an
    episode that explores the same map in less time, with the same decisions, returns
    more. A refused or blacklisted goal costs the time it wastes, and ``decision_s`` on
    top, since a goal given up at once costs no simulated time. The default scale makes a
    200 s episode return about -2 (PPO's value targets near unit scale); the gain term is a
    small shaping (about 10 % of the return on the training layouts: 0.1 s per m^2 seen),
    the completion bonus is worth 100 s and leaving the whole map unexplored 1000 s.

    Time enters the reward rather than the discount: SB3 discounts per step, and a step
    here lasts 1 to 60 s. Train with ``ppo.gamma`` near 1 (0.995 in training/gvn_v2.yaml)
    so that the discount per decision does not hide the time cost of late decisions.

    **paper** is Eq. 16-18 of the EMExplorer paper, per decision step:

    r_t = scale * (b1 dG_info - b2 dL_path + b3 r_Acc - b4), with dL_path the true path
    driven during the step (m), r_Acc the change of Eq. 18's accuracy (cells of the map
    whose class equals the ground truth's) in m^2, and b4 paid once per step.

    The paper writes G_info and L_path as totals "before time step t". Paying totals at
    every step would pay the same area again at every later step (so stalling after a
    good start would pay) and make the N_T term grow quadratically; paying the step's
    increments makes the undiscounted return telescope to exactly b1 G_info - b2 L_path +
    b3 Acc - b4 N_T of the whole episode, which is what Eq. 16 asks to trade off.

    Attributes:
        kind: 'time' or 'paper'.
        b1, b2, b3, b4: The paper's weights (paper: 1.0, 0.6, 0.5, 0.3).
        scale: Factor on the whole paper reward (keeps PPO's value targets near unit
            scale).
        time_scale: Reward per second of the time reward.
        decision_s: Seconds' worth charged per decision.
        gain_s_per_m2: Seconds' worth paid per m^2 of the map first seen.
        completion_s: Seconds' worth paid when the episode reaches the target ratio.
        shortfall_s: Seconds' worth charged for the whole map left unexplored at a short
            end (times the unexplored share).
    """

    kind: str = "time"
    b1: float = 1.0
    b2: float = 0.6
    b3: float = 0.5
    b4: float = 0.3
    scale: float = 0.1
    time_scale: float = 0.01
    decision_s: float = 1.0
    gain_s_per_m2: float = 0.1
    completion_s: float = 100.0
    shortfall_s: float = 1000.0

    def __post_init__(self) -> None:
        if self.kind not in REWARD_KINDS:
            raise ValueError(f"reward.kind must be one of {', '.join(REWARD_KINDS)}, not "
                             f"{self.kind!r}")
        if self.time_scale <= 0 or min(self.decision_s, self.gain_s_per_m2, self.completion_s,
                                       self.shortfall_s) < 0:
            raise ValueError("reward.time_scale must be > 0 and the seconds' worths >= 0")


@dataclasses.dataclass(frozen=True, kw_only=True)
class ProceduralScenes:
    """A fresh generated layout per reset.

    Attributes:
        families: Generator families drawn from (uniformly).
        width: (min, max) width in metres.
        height: (min, max) height in metres.
        cache_dir: Where generated scenes are written (None: the system temp folder).
    """

    families: tuple[str, ...] = TRAIN_FAMILIES
    width: tuple[float, float] = (12.0, 28.0)
    height: tuple[float, float] = (10.0, 20.0)
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        from mjexplore.scenes.generators import parse_family

        if not self.families:
            raise UserInputError("procedural.families must name at least one family.")
        for family in self.families:
            parse_family(family)  # An unknown family: its own error, not "widen the sizes".


@dataclasses.dataclass(frozen=True, kw_only=True)
class EnvConfig:
    """Exploration env settings.

    Attributes:
        scenes: Scene names or paths (see :func:`resolve_scene`), one drawn per reset.
        procedural: If set, a generated layout per reset instead of ``scenes``.
        episode: Episode settings (physics or kinematic dynamics, limits).
        decisions: 'ter' (TER nodes, the GVN) or 'grid' (map image and coarse goal cells,
            the CNN baseline); see :mod:`mjexplore.envs.decisions`.
        observation: TER observation layout (N_max, K, epsilon, feature set).
        grid: Grid decision space (image size, action cells).
        reward: Reward kind ('time' or 'paper') and weights.
        valid_actions: 'frontiers' (invalid action masking: frontier nodes that are not
            blacklisted) or 'all_nodes' (every TER node; the paper's "without IAM").
        max_decisions: Decisions after which an episode is truncated.
        robots: Robots exploring together. More than one: the team's decisions one at a
            time, every robot's made by the one policy
            (:class:`~mjexplore.envs.team_gvn.TeamDecisionEnv`; ``decisions`` 'ter').
    """

    scenes: tuple[str, ...] = ()
    procedural: ProceduralScenes | None = None
    episode: EpisodeConfig = dataclasses.field(default_factory=EpisodeConfig)
    decisions: str = "ter"
    observation: ObservationConfig = dataclasses.field(default_factory=ObservationConfig)
    grid: GridConfig = dataclasses.field(default_factory=GridConfig)
    reward: RewardConfig = dataclasses.field(default_factory=RewardConfig)
    valid_actions: str = "frontiers"
    max_decisions: int = 400
    robots: int = 1

    def __post_init__(self) -> None:
        if self.robots < 1 or (self.robots > 1 and self.decisions != "ter"):
            raise UserInputError(f"robots {self.robots}: give 1, or 2 or more with decisions "
                                 "'ter' (a team trains the GVN).")
        if self.decisions not in DECISIONS:
            raise UserInputError(f"decisions {self.decisions!r} is unknown: use one of "
                                 f"{', '.join(DECISIONS)}.")
        if self.valid_actions not in VALID_ACTIONS:
            raise UserInputError(f"valid_actions {self.valid_actions!r} is unknown: use one of "
                                 f"{', '.join(VALID_ACTIONS)}.")
        if not self.scenes and self.procedural is None:
            raise UserInputError("the env needs scenes: give 'scenes' or 'procedural'.")
        if self.max_decisions < 1:
            raise UserInputError(f"max_decisions must be >= 1, not {self.max_decisions}.")


def draw_scene(config: EnvConfig, rng: np.random.Generator,
               cache: dict[str, SceneFiles]) -> SceneFiles:
    """An episode's scene: one of ``config.scenes`` (loaded once into ``cache``), or a fresh
    generated layout with ``config.procedural``; drawn from ``rng``."""
    proc = config.procedural
    if proc is None:
        name = config.scenes[int(rng.integers(len(config.scenes)))]
        if name not in cache:
            cache[name] = resolve_scene(name)
        return cache[name]
    return load_scene_files(procedural_scene(proc, rng))


# Generator seeds of held-out layouts start here: the training stream draws its seeds
# below 2**31 - 1 (see :func:`procedural_scene`), so the two never share a layout.
HELDOUT_SEED_BASE = 2**31

# Generator seeds of test layouts (final figures) start here, 2**24 past the held-out ones:
# model selection and every tuning draw from HELDOUT_SEED_BASE up (at most a few hundred
# layouts), so no choice has looked at these.
TEST_SEED_BASE = HELDOUT_SEED_BASE + 2**24


def procedural_scene(proc: ProceduralScenes, rng: np.random.Generator,
                     seed: int | None = None) -> Path:
    """A generated layout's scene folder (written once into the cache, then reused).

    Family and size are drawn from ``rng``; the generator seed too, in [0, 2**31 - 1),
    unless ``seed`` is given. A draw whose size the family cannot fill is drawn again.

    Raises:
        UserInputError: No family fits the configured sizes.
    """
    from mjexplore.scenes.generate import generate_scene
    from mjexplore.scenes.scene import write_scene

    root = Path(proc.cache_dir or Path(tempfile.gettempdir()) / "mjexplore-train")
    for _ in range(20):
        family = proc.families[int(rng.integers(len(proc.families)))]
        width = round(float(rng.uniform(*proc.width)), 1)
        height = round(float(rng.uniform(*proc.height)), 1)
        drawn = int(rng.integers(2**31 - 1))
        layout_seed = drawn if seed is None else seed
        folder = root / f"{family.replace('+', '-')}_{width:g}x{height:g}_s{layout_seed}"
        if (folder / "scene.xml").is_file():
            return folder
        try:
            write_scene(generate_scene(family, width, height, layout_seed), folder)
        except UserInputError:
            continue  # A size this family cannot fill; draw again.
        return folder
    raise UserInputError("procedural scenes: no family fits the configured sizes; widen "
                         "'width'/'height'.")


def heldout_scenes(proc: ProceduralScenes, count: int, seed: int = 0,
                   base: int = HELDOUT_SEED_BASE) -> tuple[str, ...]:
    """Scene folders of ``count`` generated layouts of ``proc``'s families and sizes that
    training never draws (generator seeds from ``base``): a fixed validation set for model
    selection (:data:`HELDOUT_SEED_BASE`) or test set (:data:`TEST_SEED_BASE`, its own
    draw of families and sizes), the same for every call with these arguments."""
    rng = np.random.default_rng(seed if base == HELDOUT_SEED_BASE else [seed, base])
    return tuple(str(procedural_scene(proc, rng, base + i)) for i in range(count))


class NodeGoals:
    """The episode's explorer when goals come from outside (an agent choosing TER nodes).

    A frontier node is a frontier goal (given up once seen); any other node is a waypoint,
    driven to until reached.
    """

    name = "agent"

    def __init__(self) -> None:
        self.waypoint = False

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self.waypoint = False

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        raise RuntimeError("NodeGoals takes goals from its caller; use Episode.adopt_goal")


class ExplorationEnv(gym.Env):
    """## Description

    Lidar-based exploration of an unknown indoor scene by a simulated Turtlebot3 Waffle, as
    a sequence of goal decisions (the EMExplorer paper's POMDP). At each step the agent
    picks one node of the topological environment representation (TER, built on the
    incremental GVD of the partial map); the robot then navigates to it in MuJoCo (full
    contact physics, or the kinematic training mode) while the lidar maps, until the next
    decision is due (goal reached within zeta, its frontier seen, unreachable, or no
    progress).

    ## Action Space

    ``Discrete(N_max)``: the index of a node in the padded TER. :meth:`action_masks` gives
    the valid ones (frontier nodes, not blacklisted, under invalid action masking; every
    real node with ``valid_actions='all_nodes'``). A frontier node becomes a frontier goal,
    another node a waypoint. A padding slot is an invalid action: nothing moves and the
    step costs one decision (``decision_s``; b4 with the paper reward;
    ``info['invalid_action']``).

    ## Observation Space

    A ``Dict`` of float32 boxes: the padded TER (node features, neighbour indices, node
    mask) and the raw inputs of the episodic memory of the last epsilon decisions; the
    ``v2`` feature set adds path cost, reachability and blacklist flags per node and the
    memory's poses; see :mod:`mjexplore.envs.observation`.

    ## Rewards

    ``time`` (default): minus the simulated seconds the step took and a per-decision
    charge, a small bonus per m^2 seen, a completion bonus when explored and a charge for
    the share left unexplored when the episode ends short. ``paper``: Eq. 16-18 as
    per-step increments. See :class:`RewardConfig`. ``info`` holds each term
    (``gain_m2``, ``path_m``, ``accuracy_m2``, ``steps``, ``dt_s``; ``completion_s`` and
    ``shortfall_s`` for ``time``) and the weighted reward.

    ## Starting State

    The scene's start pose jittered by the episode seed (0.25 m, 0.3 rad); with
    ``procedural`` scenes, a fresh layout per reset. Everything is drawn from the reset
    seed: the same seed rebuilds the same scene and episode.

    ## Episode End

    Terminated when the exploration ratio reaches the target (``explored``), when no
    frontier can be reached (``no_frontiers``: while one can, a decision without a valid
    action is taken by the engine's fallback, as in evaluation) or the robot tips over.
    Truncated at the time cap (simulated), when the robot lingers, or after
    ``max_decisions`` decisions.
    ``info['end_reason']`` says which.

    ## Arguments

    ``config``: :class:`EnvConfig`.

    ## Version History

    * v0: initial version. The time reward and the v2 features came later as options
      (``reward.kind``, ``observation.features``); ``reward.kind`` defaults to ``time``,
      set ``paper`` for the original reward.
    """

    metadata = {"render_modes": []}
    # Only in a worker process: its threads per library (learning.vec_envs.worker_env).
    worker_threads: dict[str, int]

    def __init__(self, config: EnvConfig | None = None, **overrides: Any) -> None:
        config = config or EnvConfig(scenes=("loop_with_corridor",))
        self.config = dataclasses.replace(config, **overrides) if overrides else config
        cfg = self.config
        self.decisions: TerDecisions | GridDecisions
        if cfg.decisions == "ter":
            self.decisions = TerDecisions(cfg.observation, cfg.valid_actions)
            topo = cfg.episode.topology
            episode = dataclasses.replace(cfg.episode, topology=dataclasses.replace(
                topo, ter=dataclasses.replace(topo.ter, **{
                    "max_nodes": cfg.observation.max_nodes,
                    "max_neighbours": cfg.observation.max_neighbours})))
        else:
            self.decisions = GridDecisions(cfg.grid)
            episode = cfg.episode
        self._episode_config = episode
        self.observation_space = self.decisions.observation_space
        self.action_space = self.decisions.action_space
        self.goals = NodeGoals()
        self.episode: Episode | None = None
        self._reference_labels: np.ndarray | None = None  # trinary(episode.reference)
        self._scene_cache: dict[str, SceneFiles] = {}
        self._decisions = 0

    # ------------------------------------------------------------------ scenes

    def _scene(self, rng: np.random.Generator) -> SceneFiles:
        return draw_scene(self.config, rng, self._scene_cache)

    # ------------------------------------------------------------------ decisions

    def _prepare_decision(self) -> bool:
        """Builds the observation at a due decision; False if the episode is over.

        A decision without a valid action is taken by the engine's own rule, as for the
        deployed explorer: the nearest reachable frontier (counted in ``fallbacks``); the
        episode ends only when none is left, so the endgame is trained as it is evaluated.
        """
        ep = self.episode
        assert ep is not None
        while True:
            if not ep.run_to_decision():
                if ep.end_reason not in TERMINAL_REASONS and np.isfinite(ep.sim.pose).all():
                    # Cut short: PPO bootstraps from this state's value, so observe it.
                    self.decisions.prepare(ep.decision_state())
                return False
            if self.decisions.prepare(ep.decision_state()):
                return True
            if not ep.decide_fallback():
                ep.end_reason = "no_frontiers"
                return False

    def action_masks(self) -> np.ndarray:
        """Valid actions now (bool), for sb3-contrib's MaskablePPO."""
        return self.decisions.mask.copy()

    def _observation(self) -> dict[str, np.ndarray]:
        obs = self.decisions.observation()
        if "privileged" in obs:
            ep = self.episode
            assert ep is not None
            obs["privileged"] = privileged_features(
                ep.counter.count, ep.counter.total, ep.config.target_ratio,
                ep.mapper.grid.resolution ** 2)
        return obs

    def _progress(self) -> tuple[int, int, int, float]:
        """(observable cells known, accuracy in cells, kinematics rows, simulated time in
        seconds) now."""
        ep = self.episode
        assert ep is not None
        # Eq. 18's accuracy (mapping.metrics.accuracy) against the episode's labels of the
        # ground truth, made once.
        same = int((trinary(ep.mapper.grid) == self._reference_labels).sum())
        return (ep.counter.count, same,
                len(ep.sim.kinematics_rows), float(ep.sim.time))

    def _info(self) -> dict[str, Any]:
        ep = self.episode
        assert ep is not None
        return {"exploration_ratio": float(ep.curve[-1][1]), "sim_time": float(ep.sim.time),
                "decisions": self._decisions, "end_reason": ep.end_reason,
                "action_mask": self.decisions.mask.copy()}

    # ------------------------------------------------------------------ gym API

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        scene = self._scene(rng)
        self.goals = NodeGoals()
        self.episode = Episode(scene, self.goals, int(rng.integers(2**31 - 1)),
                               self._episode_config)
        self._reference_labels = trinary(self.episode.reference)
        self.decisions.reset()
        self._decisions = 0
        self._end_paid = False
        self._prepare_decision()
        self._before = self._progress()
        return self._observation(), self._info()

    def step(self, action):
        ep = self.episode
        if ep is None:
            raise RuntimeError("call reset() before step()")
        action = int(action)
        cfg = self.config.reward
        choice = None if ep.end_reason is not None else self.decisions.act(action)
        invalid = choice is None
        if not invalid:
            goal, self.goals.waypoint = choice
            ep.adopt_goal(goal)
            self._decisions += 1
            if self._prepare_decision() and self._decisions >= self.config.max_decisions:
                ep.end_reason = "decision_limit"
        known0, acc0, row0, t0 = self._before
        known1, acc1, row1, t1 = self._before = self._progress()
        cell_area = ep.mapper.grid.resolution ** 2
        xy = ep.sim.kinematics_rows[max(row0 - 1, 0):row1, 5:7]
        path = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0
        gain = (known1 - known0) * cell_area
        acc = (acc1 - acc0) * cell_area
        terms = {"gain_m2": gain, "path_m": path, "accuracy_m2": acc, "steps": 1,
                 "dt_s": t1 - t0}
        if cfg.kind == "paper":
            reward = cfg.scale * (cfg.b1 * gain - cfg.b2 * path + cfg.b3 * acc - cfg.b4)
        else:
            end = None if self._end_paid else ep.end_reason  # Charged once.
            self._end_paid = self._end_paid or end is not None
            ratio = float(ep.curve[-1][1])
            target = ep.config.target_ratio
            terms["completion_s"] = cfg.completion_s if end == "explored" else 0.0
            terms["shortfall_s"] = (cfg.shortfall_s * max(0.0, 1.0 - ratio / target)
                                    if end in SHORT_ENDS else 0.0)
            reward = cfg.time_scale * (-(t1 - t0) - cfg.decision_s + cfg.gain_s_per_m2 * gain
                                       + terms["completion_s"] - terms["shortfall_s"])
        terminated = ep.end_reason in TERMINAL_REASONS
        truncated = ep.end_reason is not None and not terminated
        info = self._info()
        info.update(terms, invalid_action=invalid, reward=reward)
        if terminated or truncated:
            info["episode_metrics"] = ep.result().metrics
        return self._observation(), float(reward), bool(terminated), bool(truncated), info
