"""The learning observation: the padded TER now and the raw inputs of the episodic memory.

The GVN's episodic memory holds, for each of the last ``epsilon`` decisions, the spatial
feature the encoder made of that decision's TER and the feature of the node chosen then.
Stored encoder outputs would go stale under PPO (the encoder changes between the rollout
and the update, and no gradient would reach it through the memory), so the observation
carries the *raw* inputs instead — each remembered decision's padded TER and its chosen
node — and the policy re-encodes them with its current weights at every forward pass.
At deployment the weights are fixed, so re-encoding and caching give the same numbers.

Three feature sets (``ObservationConfig.features``); a policy is trained on one and its
weights record which:

* ``v1``: the paper's node features, F = 6.
* ``v2``: F = 9, the v1 features and three more per node: the path cost from the robot
  along the known map (what nearest-frontier ranks by), a flag for nodes no path reaches,
  and a flag for nodes at a given-up (blacklisted) goal; and ``memory_pose``, the pose
  each remembered TER was stored at, in the current robot frame, so that the policy can
  place old TERs (whose node positions are relative to the robot of their time).
* ``v3``: F = 10, the v2 features and ``pocket`` per node: for frontier nodes the
  probability that the unseen free space behind the frontier is small (below the
  predictor's ``small_area_m2``, 0.5 m^2), from the map alone by the predictor of
  :mod:`mjexplore.topology.pockets` (``ObservationConfig.pockets``); 0 for other nodes.

Layout (N = ``max_nodes``, K = ``max_neighbours``, E = ``memory_length``; all float32 and
flat, row-major: SB3 takes only 1-D vectors and images as plain observations):

* ``node_features`` (N F): per node [px, py, G_info, phi_diff, D, flag] of the TER (see
  :mod:`mjexplore.topology.ter`; metres, radians, gain a share in [0, 1]), then for v2
  [path, unreachable, blacklisted]: path cost in metres (Costmap.distances_from, wall
  penalty included; the least over the cells within ``path_radius`` of the node, as
  nearest-frontier reads a goal; 0 when unreachable), unreachable in {0, 1}, blacklisted in
  {0, 1}; then for v3 [pocket] in [0, 1]; zero for padding.
* ``neighbours`` (N K): per node its neighbour node indices, -1 for an empty slot.
* ``node_mask`` (N): 1 for real nodes.
* ``memory_node_features`` (E N F), ``memory_neighbours`` (E N K), ``memory_node_mask``
  (E N): the TERs of the last E decisions, oldest first; slots before the episode's first
  decision are all zero (neighbours -1).
* ``memory_choice`` (E): index of the node chosen at each remembered decision.
* ``memory_mask`` (E): 1 for slots holding a decision.
* ``memory_pose`` (E 3), v2 and v3: (dx, dy, dyaw) of the robot pose each remembered TER was
  built at, in the current ``base_link`` frame (metres, radians in [-pi, pi)); a node at
  (px, py) of that TER lies at R(dyaw) (px, py) + (dx, dy) from the robot now. Zero for
  empty slots.
* ``privileged`` (2), with ``ObservationConfig.privileged`` only: ground truth for the
  critic, never the actor (an asymmetric actor-critic): the observable area still to be
  seen before the episode's target ratio, in hundreds of m^2, and the share of the
  observable area not yet seen. The training env fills them in
  (:class:`mjexplore.envs.ExplorationEnv`); anywhere else, with no ground truth, they are
  zero.

Edge lengths are not carried: a TER edge is the straight segment between its nodes, so its
length is the distance between the nodes' (px, py), which the network computes.

:func:`structured` restores the (N, F), (N, K), ... shapes.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from gymnasium import spaces

from mjexplore.topology.ter import NUM_FEATURES, PaddedTer

# Bounds of the node features (finite, as SB3 wants): positions and distances in metres,
# gain a share in [0, 1], bearing in radians, flags in {-1, 0, 1}.
FEATURE_BOUND = 1.0e4
FEATURE_SETS = ("v1", "v2", "v3")
# Node features per feature set: v2 adds path cost, unreachable and blacklisted; v3 pocket.
NODE_FEATURES = {"v1": NUM_FEATURES, "v2": NUM_FEATURES + 3, "v3": NUM_FEATURES + 4}
PATH, UNREACHABLE, BLACKLISTED = NUM_FEATURES, NUM_FEATURES + 1, NUM_FEATURES + 2
POCKET = NUM_FEATURES + 3
POSED = ("v2", "v3")  # Feature sets with path features and posed memory.
PRIVILEGED_FEATURES = 2  # [area to the target ratio / 100 m^2, share unseen]


@dataclasses.dataclass(frozen=True, kw_only=True)
class ObservationConfig:
    """Observation layout.

    Attributes:
        max_nodes: N_max, TER nodes per observation (the action space size).
        max_neighbours: K, neighbour slots per node.
        memory_length: epsilon, decisions kept in the episodic memory (paper: 10).
        features: 'v1' (the paper's node features), 'v2' (with path cost, reachability,
            blacklist flags and memory poses) or 'v3' (v2 and the predicted pocket); see
            the module docstring.
        path_radius: v2, v3: a node's path cost is the least over the cells within this
            distance of it (metres; the reach nearest-frontier gives a goal).
        privileged: Add the critic's ground-truth inputs (``privileged``, see the module
            docstring).
        pockets: v3: the pocket predictor's weights file (``mjexplore train-pockets``); a
            relative path is looked up from the working directory, then from the
            repository root (where ``training/pockets.safetensors`` lies).
        pockets_sha256: v3: if set, the first 16 hex digits of that file's sha256; another
            file is refused (a policy reads the predictor it was trained with).
    """

    max_nodes: int = 256
    max_neighbours: int = 8
    memory_length: int = 10
    features: str = "v1"
    path_radius: float = 0.5
    privileged: bool = False
    pockets: str | None = None
    pockets_sha256: str | None = None

    def __post_init__(self) -> None:
        if self.features not in FEATURE_SETS:
            raise ValueError(f"observation.features must be one of {', '.join(FEATURE_SETS)}, "
                             f"not {self.features!r}")
        if self.max_nodes < 2 or self.max_neighbours < 1 or self.memory_length < 1:
            raise ValueError("observation sizes: max_nodes >= 2, max_neighbours and "
                             "memory_length >= 1")
        if self.path_radius < 0:
            raise ValueError("observation.path_radius must be >= 0")
        if (self.features == "v3") != (self.pockets is not None):
            raise ValueError("observation.features: v3 needs observation.pockets (the pocket "
                             "predictor's weights, e.g. training/pockets.safetensors), and "
                             "pockets goes with v3 only")

    @property
    def num_features(self) -> int:
        """F, node features per node."""
        return NODE_FEATURES[self.features]


def observation_space(config: ObservationConfig) -> spaces.Dict:
    """The Dict space of :class:`TerMemory` observations."""
    n, k, e = config.max_nodes, config.max_neighbours, config.memory_length
    f = config.num_features
    feat: dict[str, Any] = dict(low=-FEATURE_BOUND, high=FEATURE_BOUND, dtype=np.float32)
    index: dict[str, Any] = dict(low=-1.0, high=float(n - 1), dtype=np.float32)
    unit: dict[str, Any] = dict(low=0.0, high=1.0, dtype=np.float32)
    space: dict[str, spaces.Space] = {
        "node_features": spaces.Box(shape=(n * f,), **feat),
        "neighbours": spaces.Box(shape=(n * k,), **index),
        "node_mask": spaces.Box(shape=(n,), **unit),
        "memory_node_features": spaces.Box(shape=(e * n * f,), **feat),
        "memory_neighbours": spaces.Box(shape=(e * n * k,), **index),
        "memory_node_mask": spaces.Box(shape=(e * n,), **unit),
        "memory_choice": spaces.Box(low=0.0, high=float(n - 1), shape=(e,), dtype=np.float32),
        "memory_mask": spaces.Box(shape=(e,), **unit),
    }
    if config.features in POSED:
        space["memory_pose"] = spaces.Box(shape=(e * 3,), **feat)
    if config.privileged:
        space["privileged"] = spaces.Box(low=0.0, high=FEATURE_BOUND,
                                         shape=(PRIVILEGED_FEATURES,), dtype=np.float32)
    return spaces.Dict(space)


def ter_arrays(padded: PaddedTer, extra: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The current-TER part of an observation; ``extra`` (N, 3 or 4) are the v2 node
    features [path, unreachable, blacklisted] (see :func:`path_features`) and for v3 the
    pocket, None for v1."""
    neighbours = np.where(padded.neighbour_mask > 0, padded.neighbours, -1).astype(np.float32)
    features = padded.node_features
    if extra is not None:
        features = np.concatenate([features, extra.astype(np.float32)], axis=1)
    return {"node_features": np.clip(features, -FEATURE_BOUND, FEATURE_BOUND),
            "neighbours": neighbours,
            "node_mask": padded.node_mask.astype(np.float32)}


def path_features(path: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """The v2 node features [path, unreachable, blacklisted] (k, 3).

    Args:
        path: (k,) path cost from the robot to each node's square, metres, inf where
            unreachable (``Costmap.distances_near``).
        allowed: (k,) False for nodes at a blacklisted goal.
    """
    reachable = np.isfinite(path)
    return np.column_stack([np.where(reachable, path, 0.0), ~reachable,
                            ~np.asarray(allowed, bool)]).astype(np.float32)


def poses_in_frame(reference: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Poses (k, 3) (x, y, yaw, one frame) expressed in the frame of the pose
    ``reference`` (3,) of that frame: (dx, dy, dyaw), metres and radians in [-pi, pi)."""
    c, s = math.cos(reference[2]), math.sin(reference[2])
    dx, dy = poses[:, 0] - reference[0], poses[:, 1] - reference[1]
    dyaw = (poses[:, 2] - reference[2] + math.pi) % (2 * math.pi) - math.pi
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, dyaw])


class TerMemory:
    """Builds observations and keeps the last ``memory_length`` decisions (a ring buffer).

    Args:
        config: Observation layout.
    """

    def __init__(self, config: ObservationConfig) -> None:
        self.config = config
        n, k, e = config.max_nodes, config.max_neighbours, config.memory_length
        self._features = np.zeros((e, n, config.num_features), np.float32)
        self._neighbours = np.full((e, n, k), -1.0, np.float32)
        self._node_mask = np.zeros((e, n), np.float32)
        self._choice = np.zeros(e, np.float32)
        self._mask = np.zeros(e, np.float32)
        self._pose = np.zeros((e, 3))  # map frame, as stored

    def reset(self) -> None:
        """Forgets every decision (a new episode)."""
        self._features[:] = 0.0
        self._neighbours[:] = -1.0
        self._node_mask[:] = 0.0
        self._choice[:] = 0.0
        self._mask[:] = 0.0
        self._pose[:] = 0.0

    def observation(self, current: dict[str, np.ndarray],
                    pose: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The full observation for the current TER arrays (from :func:`ter_arrays`) and,
        for v2 and v3, the robot's pose (x, y, yaw) in the ``map`` frame now (None:
        unknown, the memory poses read zero)."""
        obs = {**{k: v.reshape(-1).copy() for k, v in current.items()},
               "memory_node_features": self._features.reshape(-1).copy(),
               "memory_neighbours": self._neighbours.reshape(-1).copy(),
               "memory_node_mask": self._node_mask.reshape(-1).copy(),
               "memory_choice": self._choice.copy(),
               "memory_mask": self._mask.copy()}
        if self.config.features in POSED:
            relative = np.zeros_like(self._pose)
            if pose is not None:
                relative = poses_in_frame(np.asarray(pose, float), self._pose)
                relative[self._mask == 0] = 0.0
            obs["memory_pose"] = np.clip(relative, -FEATURE_BOUND, FEATURE_BOUND).astype(
                np.float32).reshape(-1)
        if self.config.privileged:
            obs["privileged"] = np.zeros(PRIVILEGED_FEATURES, np.float32)  # No ground truth.
        return obs

    def remember(self, current: dict[str, np.ndarray], choice: int,
                 pose: np.ndarray | None = None) -> None:
        """Appends a decision (the TER arrays, from :func:`ter_arrays`, it was made on, the
        node chosen and the robot's ``map`` pose then), dropping the oldest when full."""
        for buf in (self._features, self._neighbours, self._node_mask, self._choice,
                    self._mask, self._pose):
            buf[:-1] = buf[1:]
        self._features[-1] = current["node_features"].reshape(self._features.shape[1:])
        self._neighbours[-1] = current["neighbours"].reshape(self._neighbours.shape[1:])
        self._node_mask[-1] = current["node_mask"]
        self._choice[-1] = float(choice)
        self._mask[-1] = 1.0
        self._pose[-1] = 0.0 if pose is None else np.asarray(pose, float)[:3]


def privileged_features(known: int, total: int, target_ratio: float,
                        cell_area: float) -> np.ndarray:
    """The ``privileged`` entry (2,) from the observable cells known and in all (ground
    truth), the episode's target ratio and the area of a cell (m^2)."""
    total = max(total, 1)
    to_target = max(0.0, target_ratio * total - known) * cell_area
    return np.array([to_target / 100.0, 1.0 - known / total], np.float32)


def structured(obs: dict, batch_dims: int = 1) -> dict:
    """Reshapes flat observation arrays or tensors (with ``batch_dims`` leading axes) to
    (..., N, F), (..., N, K), (..., N), (..., E, N, F), (..., E, N, K), (..., E, N),
    (..., E), (..., E) and, for v2 and v3, (..., E, 3)."""
    lead = tuple(obs["node_mask"].shape[:batch_dims])
    n = obs["node_mask"].shape[-1]
    e = obs["memory_mask"].shape[-1]
    k = obs["neighbours"].shape[-1] // n
    f = obs["node_features"].shape[-1] // n
    shapes = {"node_features": (n, f), "neighbours": (n, k), "node_mask": (n,),
              "memory_node_features": (e, n, f), "memory_neighbours": (e, n, k),
              "memory_node_mask": (e, n), "memory_choice": (e,), "memory_mask": (e,)}
    if "memory_pose" in obs:
        shapes["memory_pose"] = (e, 3)
    return {key: obs[key].reshape(*lead, *shape) for key, shape in shapes.items()}
