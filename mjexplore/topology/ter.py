"""The topological environment representation (TER) of the paper, built on the GVD.

Nodes: the GVD graph's vertices, one node per frontier (at the frontier's goal cell) and
the robot node. The robot and the frontiers are joined to the graph by the shortest
straight segment over known free cells to a GVD vertex (the nearest one that can be
reached in a straight line). Only the GVD component the robot joins is kept (pieces of the
diagram cut off from it are out of reach); a frontier no kept vertex can see is joined to
the robot node if the robot sees it, and left out otherwise (no path to it is known).
Every edge is a straight, collision-free segment on the known map; its feature is its
Euclidean length.

Node features S = [px, py, G_info, phi_diff, D, flag] (paper Eq. 7):
    px, py: the node's position *relative to the robot*, in the robot's frame (x forward,
        y left), metres. The paper's text reads "the current position of the robot",
        which would give every node the same value; a robot-relative position is what makes
        the feature informative and translation-invariant, so that is used here.
    G_info: the frontier's information gain for frontier nodes; for the other nodes a
        discounted gain: the largest gain of a frontier within ``gain_radius`` (D_gain,
        5 m), times (1 - distance / D_gain).
    phi_diff: bearing of the node from the robot's heading, radians in [-pi, pi).
    D: Euclidean distance from the robot, metres.
    flag: 0 for the robot node, 1 for frontier nodes, -1 for the others.

:meth:`Ter.padded` lays the graph out in fixed-size arrays for learning (node features,
neighbour indices with a mask, edge lengths, node mask, action mask).
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mjexplore.maps import GridMap
from mjexplore.topology.frontiers import Frontier
from mjexplore.topology.graph import GvdGraph, segment_free_cells

ROBOT_FLAG, FRONTIER_FLAG, OTHER_FLAG = 0.0, 1.0, -1.0
NUM_FEATURES = 6


@dataclasses.dataclass(frozen=True, kw_only=True)
class TerConfig:
    """TER settings.

    Attributes:
        gain_radius: D_gain, the reach of a frontier's discounted gain, metres.
        max_link_candidates: How many nearest GVD vertices are tried when joining a
            frontier or the robot to the graph.
        max_nodes: N_max of the padded arrays.
        max_neighbours: Neighbour slots per node in the padded arrays.
    """

    gain_radius: float = 5.0
    max_link_candidates: int = 12
    max_nodes: int = 256
    max_neighbours: int = 8


@dataclasses.dataclass(frozen=True)
class PaddedTer:
    """Fixed-size arrays of a TER (all finite).

    Attributes:
        node_features: float32 (N_max, 6).
        neighbours: int32 (N_max, K) neighbour node indices (0 where unused).
        neighbour_mask: float32 (N_max, K), 1 where ``neighbours`` is a real edge.
        edge_lengths: float32 (N_max, K) edge lengths in metres (0 where unused).
        node_mask: float32 (N_max,), 1 for real nodes.
        action_mask: bool (N_max,), True for frontier nodes (the valid goals).
        node_positions: float32 (N_max, 2) positions in the ``map`` frame, metres.
    """

    node_features: np.ndarray
    neighbours: np.ndarray
    neighbour_mask: np.ndarray
    edge_lengths: np.ndarray
    node_mask: np.ndarray
    action_mask: np.ndarray
    node_positions: np.ndarray


@dataclasses.dataclass(frozen=True)
class Ter:
    """A TER.

    Attributes:
        positions: (n, 2) node positions in the ``map`` frame, metres.
        flags: (n,) 0 robot, 1 frontier, -1 other.
        edges: (m, 2) node index pairs (i < j).
        lengths: (m,) Euclidean edge lengths, metres.
        features: (n, 6) node features [px, py, G_info, phi_diff, D, flag].
        frontier_index: (n,) index into the frontier list for frontier nodes, -1 otherwise.
        robot: index of the robot node.
    """

    positions: np.ndarray
    flags: np.ndarray
    edges: np.ndarray
    lengths: np.ndarray
    features: np.ndarray
    frontier_index: np.ndarray
    robot: int

    def padded(self, config: TerConfig | None = None) -> PaddedTer:
        """The TER in fixed-size arrays.

        Beyond ``max_nodes`` nodes, the robot and frontier nodes are kept first, then the
        other nodes nearest to the robot; beyond ``max_neighbours`` edges, a node keeps its
        shortest ones.
        """
        config = config or TerConfig()
        n_max, k_max = config.max_nodes, config.max_neighbours
        n = len(self.positions)
        priority = np.where(self.flags == OTHER_FLAG, 1.0, 0.0) * 1e9 + self.features[:, 4]
        order = np.argsort(priority, kind="stable")[:n_max]
        new_index = np.full(n, -1, np.int64)
        new_index[order] = np.arange(len(order))
        out_feat = np.zeros((n_max, NUM_FEATURES), np.float32)
        out_feat[: len(order)] = self.features[order]
        neighbours = np.zeros((n_max, k_max), np.int32)
        neighbour_mask = np.zeros((n_max, k_max), np.float32)
        edge_lengths = np.zeros((n_max, k_max), np.float32)
        fill = np.zeros(n_max, np.int64)
        for e in np.argsort(self.lengths, kind="stable"):
            a, b = new_index[self.edges[e]]
            if a < 0 or b < 0:
                continue
            for u, v in ((a, b), (b, a)):
                if fill[u] < k_max:
                    neighbours[u, fill[u]] = v
                    neighbour_mask[u, fill[u]] = 1.0
                    edge_lengths[u, fill[u]] = self.lengths[e]
                    fill[u] += 1
        node_mask = np.zeros(n_max, np.float32)
        node_mask[: len(order)] = 1.0
        action_mask = np.zeros(n_max, bool)
        action_mask[: len(order)] = self.flags[order] == FRONTIER_FLAG
        positions = np.zeros((n_max, 2), np.float32)
        positions[: len(order)] = self.positions[order]
        return PaddedTer(out_feat, neighbours, neighbour_mask, edge_lengths, node_mask,
                         action_mask, positions)


@numba.njit(cache=True)
def _link_many(free, points, targets, origin_x, origin_y, resolution, k):
    out = np.full(len(points), -1, np.int64)
    if len(targets) == 0:
        return out
    for m in range(len(points)):
        dx = targets[:, 0] - points[m, 0]
        dy = targets[:, 1] - points[m, 1]
        order = np.argsort(np.sqrt(dx * dx + dy * dy), kind="mergesort")
        r0 = (points[m, 1] - origin_y) / resolution - 0.5
        c0 = (points[m, 0] - origin_x) / resolution - 0.5
        for j in range(min(k, len(targets))):
            i = order[j]
            r1 = (targets[i, 1] - origin_y) / resolution - 0.5
            c1 = (targets[i, 0] - origin_x) / resolution - 0.5
            if segment_free_cells(free, r0, c0, r1, c1):
                out[m] = i
                break
    return out


def _link(free: np.ndarray, grid: GridMap, points: np.ndarray, targets: np.ndarray,
          k: int) -> np.ndarray:
    """For each of ``points`` (m, 2), the index of the nearest of ``targets`` (map-frame
    points, metres) among the ``k`` nearest that a free straight segment joins it to; -1
    if none. Ties in distance go to the lower index."""
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    targets = np.ascontiguousarray(targets, np.float64).reshape(-1, 2)
    return _link_many(free, points, targets, float(grid.origin[0]), float(grid.origin[1]),
                      float(grid.resolution), int(k))


def build_ter(graph: GvdGraph, grid: GridMap, frontiers: list[Frontier], gains: np.ndarray,
              robot_pose: np.ndarray, config: TerConfig | None = None,
              free: np.ndarray | None = None) -> Ter:
    """Assembles the TER from a GVD graph, frontiers with their gains and the robot pose.

    Args:
        graph: GVD graph in cell coordinates of ``grid``.
        grid: The partial map (its free cells bound the links).
        frontiers: Frontiers of the map.
        gains: Information gain of each frontier.
        robot_pose: (x, y, yaw) of the robot in the ``map`` frame.
        config: TER settings.
        free: ``grid.free`` if already computed.
    """
    config = config or TerConfig()
    free = grid.free if free is None else free
    robot_xy = np.asarray(robot_pose[:2], float)
    gvd_xy = grid.cell_to_world(graph.positions) if len(graph.positions) else np.zeros((0, 2))
    # Keep the GVD component the robot joins; other pieces are out of the robot's reach.
    anchor = int(_link(free, grid, robot_xy, gvd_xy, config.max_link_candidates)[0])
    keep = np.zeros(len(gvd_xy), bool)
    if anchor >= 0:
        n = len(gvd_xy)
        adjacency = coo_matrix((np.ones(len(graph.edges)), tuple(graph.edges.T)), shape=(n, n))
        _, labels = connected_components(adjacency, directed=False)
        keep = labels == labels[anchor]
    index = np.cumsum(keep) - 1
    gvd_xy = gvd_xy[keep]
    gvd_edges = index[graph.edges[keep[graph.edges].all(axis=1)]] if len(graph.edges) else (
        np.zeros((0, 2), np.int64))
    n_gvd = len(gvd_xy)
    robot = n_gvd
    positions = [gvd_xy, robot_xy[None]]
    flags = [np.full(n_gvd, OTHER_FLAG), np.array([ROBOT_FLAG])]
    new_edges = [(int(index[anchor]), robot)] if anchor >= 0 else []
    frontier_index = [np.full(n_gvd + 1, -1)]
    goals = np.array([f.goal for f in frontiers], float).reshape(-1, 2)
    link = _link(free, grid, goals, gvd_xy, config.max_link_candidates)
    sees_robot = _link(free, grid, goals[link < 0], robot_xy[None], 1) == 0
    link[np.flatnonzero(link < 0)[sees_robot]] = robot
    kept = np.flatnonzero(link >= 0).tolist()
    new_edges += [(int(link[i]), n_gvd + 1 + n) for n, i in enumerate(kept)]
    if kept:
        positions.append(np.array([frontiers[i].goal for i in kept]))
        flags.append(np.full(len(kept), FRONTIER_FLAG))
        frontier_index.append(np.array(kept))
    positions_arr = np.concatenate(positions).reshape(-1, 2)
    flags_arr = np.concatenate(flags)
    edges_arr = np.concatenate([gvd_edges.reshape(-1, 2),
                                np.array(new_edges, np.int64).reshape(-1, 2)])
    edges_arr = np.sort(edges_arr, axis=1)
    lengths = np.linalg.norm(positions_arr[edges_arr[:, 0]] - positions_arr[edges_arr[:, 1]],
                             axis=1)
    node_gain = np.zeros(len(positions_arr))
    if kept:
        f_gain = np.asarray(gains, float)[kept]
        f_xy = positions_arr[flags_arr == FRONTIER_FLAG]
        node_gain[flags_arr == FRONTIER_FLAG] = f_gain
        others = flags_arr != FRONTIER_FLAG
        d = np.linalg.norm(positions_arr[others, None, :] - f_xy[None], axis=2)
        discount = np.clip(1.0 - d / config.gain_radius, 0.0, None)
        node_gain[others] = (discount * f_gain[None]).max(axis=1)
    rel = positions_arr - robot_xy
    yaw = float(robot_pose[2])
    c, s = math.cos(yaw), math.sin(yaw)
    px = c * rel[:, 0] + s * rel[:, 1]
    py = -s * rel[:, 0] + c * rel[:, 1]
    features = np.column_stack([px, py, node_gain, np.arctan2(py, px), np.hypot(px, py),
                                flags_arr]).astype(np.float64)
    return Ter(positions_arr, flags_arr, edges_arr, lengths, features,
               np.concatenate(frontier_index), robot)
