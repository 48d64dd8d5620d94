"""What a learned explorer sees and chooses at a decision: two decision spaces.

* :class:`TerDecisions` (GVN): observation = the padded TER and the raw episodic memory;
  action = a TER node (a frontier node becomes a frontier goal, another node a waypoint).
* :class:`GridDecisions` (the paper's "Naive Exp" CNN baseline, its ref. [27]):
  observation = the whole map resized to S x S pixels in five channels; action = a cell of a
  coarse K x K grid over the map; the goal is the reachable frontier nearest that cell.

The whole map (not a robot-centred crop) is used for the grid because the action is a
*global* goal anywhere on the map: a crop would hide the places the policy must be able
to pick, and the map's extent is known from the start (the mapper's grid has the scene's
size), so the resized image keeps a fixed scale per scene.

Both take only an :class:`~mjexplore.episode.explorer.ExplorationState`, so the env and the
deployed explorers share them.
"""

from __future__ import annotations

import dataclasses
from typing import cast

import cv2
import numpy as np
from gymnasium import spaces

from mjexplore.envs.observation import (
    POSED,
    ObservationConfig,
    TerMemory,
    observation_space,
    path_features,
    ter_arrays,
)
from mjexplore.episode.explorer import ExplorationState
from mjexplore.topology.frontiers import Frontier
from mjexplore.topology.pipeline import TopologyConfig
from mjexplore.topology.ter import FRONTIER_FLAG, PaddedTer, TerConfig

GRID_CHANNELS = ("free", "occupied", "unknown", "robot", "trajectory")


def ter_action_mask(ter_padded: PaddedTer, state: ExplorationState,
                    valid_actions: str) -> np.ndarray:
    """Valid actions of a padded TER: frontier nodes not blacklisted, or all real nodes."""
    real = ter_padded.node_mask > 0
    if valid_actions == "all_nodes":
        mask = real.copy()
        mask[real] = state.allowed(ter_padded.node_positions[real])
        return mask
    mask = ter_padded.action_mask.copy()
    if mask.any():
        mask[mask] = state.allowed(ter_padded.node_positions[mask])
    return mask


class TerDecisions:
    """TER-node decisions (see the module docstring).

    Args:
        config: Observation layout (N_max, K, epsilon, feature set).
        valid_actions: 'frontiers' (invalid action masking) or 'all_nodes'.
        topology: TER settings to build the TER with (information gain kind and window,
            D_gain, link candidates), as a policy was trained with; None builds it with the
            episode's own tracker settings. Frontiers and the GVD are the episode's either
            way.
    """

    def __init__(self, config: ObservationConfig, valid_actions: str = "frontiers",
                 topology: TopologyConfig | None = None) -> None:
        self.config = config
        self.valid_actions = valid_actions
        self.topology = topology
        ter = topology.ter if topology is not None else TerConfig()
        self.ter_config = dataclasses.replace(ter, max_nodes=config.max_nodes,
                                              max_neighbours=config.max_neighbours)
        self.observation_space = observation_space(config)
        self.action_space = spaces.Discrete(config.max_nodes)
        self.memory = TerMemory(config)
        self.pockets = None
        if config.features == "v3":
            from mjexplore.topology.pockets import pocket_predictor

            assert config.pockets is not None  # ObservationConfig: v3 goes with pockets.
            self.pockets = pocket_predictor(config.pockets, config.pockets_sha256)
        self.reset()

    def reset(self) -> None:
        self.memory.reset()
        self.padded: PaddedTer | None = None  # The TER of the current decision...
        self.current: dict[str, np.ndarray] | None = None  # ...as observation arrays...
        self.pose: np.ndarray | None = None  # ...and the robot's map pose then.
        self.mask = np.zeros(self.config.max_nodes, bool)
        self.pocket_memo: dict[bytes, np.float32] = {}  # The episode's pocket predictions.

    def _extra_features(self, padded: PaddedTer, state: ExplorationState,
                        frontiers: list[Frontier]) -> np.ndarray:
        """The v2 node features [path, unreachable, blacklisted] (N, 3) of a padded TER
        (one Dijkstra from the robot over the costmap per decision), and for v3 the
        frontier nodes' pocket probability beside them (N, 4)."""
        real = padded.node_mask > 0
        extra = np.zeros((len(real), 3 if self.pockets is None else 4), np.float32)
        if real.any():
            grid = state.grid
            positions = padded.node_positions[real]
            half = int(round(self.config.path_radius / grid.resolution))
            cells = np.clip(grid.world_to_cell(positions), 0, np.array(grid.shape) - 1)
            path = state.costmap.distances_near(state.pose[:2], cells, half)
            extra[real, :3] = path_features(path, state.allowed(positions))
        if self.pockets is not None and frontiers:
            extra[:, 3] = self.pockets.node_probability(padded, state.grid, frontiers,
                                                         self.pocket_memo)
        return extra

    def prepare(self, state: ExplorationState) -> bool:
        """Builds the observation and mask; False when no valid frontier is left (the
        observation is still that of ``state``, the mask then empty)."""
        tracker = state.extras["tracker"]
        ter, frontiers, _ = tracker.ter(state.grid, state.pose, self.topology)
        state.extras["ter"] = ter
        padded = ter.padded(self.ter_config)
        mask = ter_action_mask(padded, state, "frontiers")
        valid = bool(mask.any())
        if valid and self.valid_actions == "all_nodes":
            mask = ter_action_mask(padded, state, "all_nodes")
        self.padded, self.mask = padded, mask
        extra = (self._extra_features(padded, state, frontiers)
                 if self.config.features in POSED else None)
        self.current = ter_arrays(padded, extra)
        self.pose = np.asarray(state.pose, float).copy()
        return valid

    def observation(self) -> dict[str, np.ndarray]:
        if self.current is None:  # Over before any decision: an empty TER.
            self.current = {k: np.zeros(cast(spaces.Box, v).shape, np.float32)
                             for k, v in self.observation_space.spaces.items()
                             if not k.startswith("memory")}
            self.current["neighbours"][:] = -1.0
        return self.memory.observation(self.current, self.pose)

    def action_positions(self) -> np.ndarray:
        """(N_max, 2) map-frame positions (m) of the actions: the nodes (padding at 0)."""
        assert self.padded is not None  # Read at a decision, after prepare().
        return self.padded.node_positions

    def act(self, action: int) -> tuple[np.ndarray, bool] | None:
        """(goal (x, y), is_waypoint) for a node, or None for a padding slot."""
        p = self.padded
        if p is None or not 0 <= action < len(p.node_mask) or p.node_mask[action] <= 0:
            return None
        assert self.current is not None  # prepare() sets it with padded.
        self.memory.remember(self.current, action, self.pose)
        waypoint = bool(p.node_features[action, 5] != FRONTIER_FLAG)
        return p.node_positions[action].astype(float), waypoint


@dataclasses.dataclass(frozen=True, kw_only=True)
class GridConfig:
    """Grid decision space.

    Attributes:
        image_size: S, pixels per side of the resized map.
        action_cells: K, coarse cells per side of the action grid.
    """

    image_size: int = 64
    action_cells: int = 16

    def __post_init__(self) -> None:
        if self.image_size < 16 or self.action_cells < 2:
            raise ValueError("image_size must be >= 16 and action_cells >= 2")


class GridDecisions:
    """Map-image decisions (see the module docstring).

    The map is placed in the lower-left corner of a square of side max(rows, cols) cells
    (the rest reads as unknown), so image pixels and action cells are square in metres.
    Channels, each in [0, 1] (area fractions after resizing): free, occupied, unknown,
    robot (a 3 x 3 pixel mark), trajectory (pixels the robot passed).
    """

    def __init__(self, config: GridConfig) -> None:
        self.config = config
        s, k = config.image_size, config.action_cells
        self.observation_space = spaces.Dict({"image": spaces.Box(
            0.0, 1.0, shape=(len(GRID_CHANNELS) * s * s,), dtype=np.float32)})
        self.action_space = spaces.Discrete(k * k)
        self.reset()

    def reset(self) -> None:
        s = self.config.image_size
        self._image = np.zeros((len(GRID_CHANNELS), s, s), np.float32)
        self._image[2] = 1.0
        self.mask = np.zeros(self.config.action_cells ** 2, bool)
        self._targets: list[np.ndarray] = []
        self._state: ExplorationState | None = None

    def _square(self, layer: np.ndarray, side: int, fill: float) -> np.ndarray:
        out = np.full((side, side), fill, np.float32)
        out[:layer.shape[0], :layer.shape[1]] = layer
        return out

    def cell_centres(self, state: ExplorationState) -> np.ndarray:
        """(K*K, 2) map-frame centres of the action cells, row-major from the lower left."""
        g = state.grid
        side = max(g.shape) * g.resolution
        k = self.config.action_cells
        c = (np.arange(k) + 0.5) * side / k
        yy, xx = np.meshgrid(c, c, indexing="ij")
        return np.column_stack([g.origin[0] + xx.ravel(), g.origin[1] + yy.ravel()])

    def prepare(self, state: ExplorationState) -> bool:
        """Builds the image and mask; False when no reachable frontier is left (the image
        is still that of ``state``, the mask then empty)."""
        g = state.grid
        reachable = (np.isfinite(state.frontier_distances()) if state.frontiers else
                     np.zeros(0, bool))
        self._targets = [f.goal for f, ok in zip(state.frontiers, reachable) if ok]
        self._state = state
        s, k = self.config.image_size, self.config.action_cells
        side = max(g.shape)
        data = g.data
        layers = [(data == 0), (data > 0), (data < 0)]
        img = self._image
        for i, (layer, fill) in enumerate(zip(layers, (0.0, 0.0, 1.0))):
            img[i] = cv2.resize(self._square(layer.astype(np.float32), side, fill)[::-1], (s, s),
                                interpolation=cv2.INTER_AREA)
        np.clip(img[:3], 0.0, 1.0, out=img[:3])  # Resampling round-off.
        img[3:] = 0.0
        scale = s / (side * g.resolution)

        def pixel(xy: np.ndarray) -> np.ndarray:
            col = (xy[:, 0] - g.origin[0]) * scale
            row = s - 1 - (xy[:, 1] - g.origin[1]) * scale
            return np.clip(np.column_stack([row, col]).astype(int), 0, s - 1)

        r, c = pixel(np.asarray(state.pose[:2])[None])[0]
        img[3, max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] = 1.0
        if len(state.visited):
            rc = pixel(np.asarray(state.visited))
            img[4, rc[:, 0], rc[:, 1]] = 1.0
        # Valid cells: a known free cell or a frontier cell inside.
        fine = (data == 0).copy()
        for f in state.frontiers:
            fine[f.cells[:, 0], f.cells[:, 1]] = True
        sq = self._square(fine.astype(np.float32), side, 0.0)
        edges = np.linspace(0, side, k + 1).round().astype(int)
        rows_any = np.maximum.reduceat(sq, edges[:-1], axis=0)
        cells = np.maximum.reduceat(rows_any, edges[:-1], axis=1)
        self.mask = (cells.reshape(-1) > 0) & bool(self._targets)
        return bool(self._targets)

    def observation(self) -> dict[str, np.ndarray]:
        return {"image": self._image.reshape(-1).copy()}

    def action_positions(self) -> np.ndarray:
        """(K*K, 2) map-frame positions (m) of the actions: the cell centres."""
        assert self._state is not None  # Read at a decision, after prepare().
        return self.cell_centres(self._state)

    def act(self, action: int) -> tuple[np.ndarray, bool] | None:
        """The reachable frontier nearest the chosen cell's centre (never a waypoint)."""
        if self._state is None or not 0 <= action < len(self.mask) or not self._targets:
            return None
        centre = self.cell_centres(self._state)[action]
        targets = np.array(self._targets)
        return targets[int(np.argmin(np.linalg.norm(targets - centre, axis=1)))], False
