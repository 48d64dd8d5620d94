"""The learning observation: the padded TER now and the raw inputs of the episodic memory.

The GVN's episodic memory holds, for each of the last ``epsilon`` decisions, the spatial
feature the encoder made of that decision's TER and the feature of the node chosen then.
Stored encoder outputs would go stale under PPO (the encoder changes between the rollout
and the update, and no gradient would reach it through the memory), so the observation
carries the *raw* inputs instead — each remembered decision's padded TER and its chosen
node — and the policy re-encodes them with its current weights at every forward pass.
At deployment the weights are fixed, so re-encoding and caching give the same numbers.

Layout (N = ``max_nodes``, K = ``max_neighbours``, E = ``memory_length``; all float32 and
flat, row-major: SB3 takes only 1-D vectors and images as plain observations):

* ``node_features`` (N 6): per node [px, py, G_info, phi_diff, D, flag] of the TER (see
  :mod:`mjexplore.topology.ter`; metres, radians, gain a share in [0, 1]); zero for
  padding.
* ``neighbours`` (N K): per node its neighbour node indices, -1 for an empty slot.
* ``node_mask`` (N): 1 for real nodes.
* ``memory_node_features`` (E N 6), ``memory_neighbours`` (E N K), ``memory_node_mask``
  (E N): the TERs of the last E decisions, oldest first; slots before the episode's first
  decision are all zero (neighbours -1).
* ``memory_choice`` (E): index of the node chosen at each remembered decision.
* ``memory_mask`` (E): 1 for slots holding a decision.

:func:`structured` restores the (N, 6), (N, K), ... shapes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from gymnasium import spaces

from mjexplore.topology.ter import NUM_FEATURES, PaddedTer

# Bounds of the node features (finite, as SB3 wants): positions and distances in metres,
# gain a share in [0, 1], bearing in radians, flag in {-1, 0, 1}.
FEATURE_BOUND = 1.0e4


@dataclasses.dataclass(frozen=True, kw_only=True)
class ObservationConfig:
    """Observation layout.

    Attributes:
        max_nodes: N_max, TER nodes per observation (the action space size).
        max_neighbours: K, neighbour slots per node.
        memory_length: epsilon, decisions kept in the episodic memory (paper: 10).
    """

    max_nodes: int = 256
    max_neighbours: int = 8
    memory_length: int = 10


def observation_space(config: ObservationConfig) -> spaces.Dict:
    """The Dict space of :class:`TerMemory` observations."""
    n, k, e = config.max_nodes, config.max_neighbours, config.memory_length
    feat = dict(low=-FEATURE_BOUND, high=FEATURE_BOUND, dtype=np.float32)
    index = dict(low=-1.0, high=float(n - 1), dtype=np.float32)
    unit = dict(low=0.0, high=1.0, dtype=np.float32)
    return spaces.Dict({
        "node_features": spaces.Box(shape=(n * NUM_FEATURES,), **feat),
        "neighbours": spaces.Box(shape=(n * k,), **index),
        "node_mask": spaces.Box(shape=(n,), **unit),
        "memory_node_features": spaces.Box(shape=(e * n * NUM_FEATURES,), **feat),
        "memory_neighbours": spaces.Box(shape=(e * n * k,), **index),
        "memory_node_mask": spaces.Box(shape=(e * n,), **unit),
        "memory_choice": spaces.Box(low=0.0, high=float(n - 1), shape=(e,), dtype=np.float32),
        "memory_mask": spaces.Box(shape=(e,), **unit),
    })


def ter_arrays(padded: PaddedTer) -> dict[str, np.ndarray]:
    """The current-TER part of an observation."""
    neighbours = np.where(padded.neighbour_mask > 0, padded.neighbours, -1).astype(np.float32)
    return {"node_features": np.clip(padded.node_features, -FEATURE_BOUND, FEATURE_BOUND),
            "neighbours": neighbours,
            "node_mask": padded.node_mask.astype(np.float32)}


class TerMemory:
    """Builds observations and keeps the last ``memory_length`` decisions (a ring buffer).

    Args:
        config: Observation layout.
    """

    def __init__(self, config: ObservationConfig) -> None:
        self.config = config
        n, k, e = config.max_nodes, config.max_neighbours, config.memory_length
        self._features = np.zeros((e, n, NUM_FEATURES), np.float32)
        self._neighbours = np.full((e, n, k), -1.0, np.float32)
        self._node_mask = np.zeros((e, n), np.float32)
        self._choice = np.zeros(e, np.float32)
        self._mask = np.zeros(e, np.float32)

    def reset(self) -> None:
        """Forgets every decision (a new episode)."""
        self._features[:] = 0.0
        self._neighbours[:] = -1.0
        self._node_mask[:] = 0.0
        self._choice[:] = 0.0
        self._mask[:] = 0.0

    def observation(self, current: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The full observation for the current TER arrays (from :func:`ter_arrays`)."""
        return {**{k: v.reshape(-1).copy() for k, v in current.items()},
                "memory_node_features": self._features.reshape(-1).copy(),
                "memory_neighbours": self._neighbours.reshape(-1).copy(),
                "memory_node_mask": self._node_mask.reshape(-1).copy(),
                "memory_choice": self._choice.copy(),
                "memory_mask": self._mask.copy()}

    def remember(self, current: dict[str, np.ndarray], choice: int) -> None:
        """Appends a decision (the TER arrays, from :func:`ter_arrays`, it was made on and
        the node chosen), dropping the oldest when full."""
        for buf in (self._features, self._neighbours, self._node_mask, self._choice,
                    self._mask):
            buf[:-1] = buf[1:]
        self._features[-1] = current["node_features"].reshape(self._features.shape[1:])
        self._neighbours[-1] = current["neighbours"].reshape(self._neighbours.shape[1:])
        self._node_mask[-1] = current["node_mask"]
        self._choice[-1] = float(choice)
        self._mask[-1] = 1.0


def structured(obs: dict, batch_dims: int = 1) -> dict:
    """Reshapes flat observation arrays or tensors (with ``batch_dims`` leading axes) to
    (..., N, 6), (..., N, K), (..., N), (..., E, N, 6), (..., E, N, K), (..., E, N),
    (..., E), (..., E)."""
    lead = tuple(obs["node_mask"].shape[:batch_dims])
    n = obs["node_mask"].shape[-1]
    e = obs["memory_mask"].shape[-1]
    k = obs["neighbours"].shape[-1] // n
    shapes = {"node_features": (n, NUM_FEATURES), "neighbours": (n, k), "node_mask": (n,),
              "memory_node_features": (e, n, NUM_FEATURES), "memory_neighbours": (e, n, k),
              "memory_node_mask": (e, n), "memory_choice": (e,), "memory_mask": (e,)}
    return {key: obs[key].reshape(*lead, *shape) for key, shape in shapes.items()}
