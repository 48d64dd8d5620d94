"""The Generalized Voronoi Network (GVN) of the EMExplorer paper, in plain torch.

Pipeline for one decision (paper Fig. 3), B observations of N TER nodes:

1. Spatial encoder E_S: a 3-layer GCN with symmetric normalisation and residual
   connections (Eq. 8) turns the node features into node embeddings r^G (B, N, d).
2. Episodic memory: each of the last epsilon decisions is re-encoded by the same E_S from
   its TER (carried raw in the observation, see :mod:`mjexplore.envs.observation`); its
   memory fragment is the mean node embedding of that TER joined with the embedding of the
   node chosen then (the "frontier feature"). A batch encodes each distinct TER once: in a
   PPO minibatch a TER recurs as the current one and in the next epsilon memories.
3. Temporal encoder E_T: a dilated causal TCN over the fragments (Eq. 9); its output at the
   last decision is h^M (B, d).
4. Attention fusion (Eq. 10-11), per node: alpha = softmax(w.r_i + b, w.h^M + b),
   h_i = alpha_1 r_i + alpha_2 h^M.
5. Aggregator (Eq. 12): z_i = MLP(cat(h_i, r_i)) with ReLU.
6. Actor head: one logit per node (an MLP shared by all nodes); critic head: an MLP of the
   masked mean and max of z.

The paper models the policy as a Gaussian; with one TER node per action the natural and
here used form is a categorical distribution over node logits (masked, Eq. 14-15).

The ``v2`` network (for the ``v2`` observation, see :mod:`mjexplore.envs.observation`)
changes three things and keeps the rest:

* E_S passes messages filtered by edge length: node i gets W_s g_i + sum_b W_b (mean over
  its neighbours j of phi_b(l_ij) g_j), phi_b Gaussians of the edge's length l_ij (the
  distance between the nodes, computed from their features), so each channel can weigh a
  0.3 m hop and a 5 m one differently (three GCN hops of the paper reach about 6 m).
* Each memory fragment also gets where the remembered TER was stored: the stored pose in
  the current robot frame and the chosen node's position in the current frame.
* After E_S, ``attention_layers`` pre-norm transformer layers attend over all nodes of
  the current TER and the memory summary h^M (one token), so every node sees the whole
  graph whatever its hop distance.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections import OrderedDict

import torch
from torch import nn
from torch.nn import functional as F

from mjexplore.envs.observation import (
    BLACKLISTED,
    FEATURE_BOUND,
    PATH,
    POCKET,
    UNREACHABLE,
    structured,
)
from mjexplore.topology.ter import NUM_FEATURES

# Fixed input scaling of [px, py, G_info, phi_diff, D, flag]: metres / 10, radians / pi;
# v2 adds [path, unreachable, blacklisted]: metres / 10, flags as they are; v3 [pocket],
# a probability.
FEATURE_SCALE = (0.1, 0.1, 1.0, 1.0 / torch.pi, 0.1, 1.0)
FEATURE_SCALE_V2 = FEATURE_SCALE + (0.1, 1.0, 1.0, 1.0)
METRES_SCALE = 0.1
POSE_FEATURES = 6  # v2 memory: the stored pose (dx, dy, cos, sin) and the chosen node (x, y)
# v2 edge-length basis: Gaussian centres and widths in metres (TER edges: GVD sides of up to
# 2 m, links to frontiers and the robot of up to the lidar's range).
LENGTH_BASIS = ((0.5, 1.5, 3.0, 6.0), (0.5, 1.0, 1.5, 3.0))
# Nodes whose features, with the node count, sort graphs before the full comparison in
# distinct_graphs (the robot and the nearest frontiers: they differ between decisions).
KEY_NODES = 4


@dataclasses.dataclass(frozen=True, kw_only=True)
class GvnConfig:
    """GVN sizes.

    Attributes:
        hidden: Width d of node embeddings, memory fragments and the TCN.
        gcn_layers: GCN layers of E_S (paper: 3).
        tcn_kernel: TCN kernel size K.
        tcn_dilations: Dilation d_l of each TCN layer (receptive field 1 + (K-1) sum d_l,
            which must cover epsilon).
        features: The observation's feature set, 'v1' (the paper's network) or 'v2'
            (edge-gated messages, posed memory, global attention; module docstring).
        attention_layers: v2: transformer layers over the current TER's nodes.
        attention_heads: v2: heads per attention layer (must divide ``hidden``).
    """

    hidden: int = 64
    gcn_layers: int = 3
    tcn_kernel: int = 3
    tcn_dilations: tuple[int, ...] = (1, 2, 4)
    features: str = "v1"
    attention_layers: int = 1
    attention_heads: int = 4

    def __post_init__(self) -> None:
        if self.features not in ("v1", "v2"):
            raise ValueError(f"features must be 'v1' or 'v2', not {self.features!r}")
        if self.features == "v2" and (self.attention_layers < 1 or self.attention_heads < 1
                                      or self.hidden % self.attention_heads):
            raise ValueError("v2 needs attention_layers >= 1 and attention_heads >= 1 "
                             "dividing hidden")


# The nearest-node prior counts a node the robot cannot reach, or whose goal is blacklisted,
# this much farther (m): beyond any path (paths are clipped at FEATURE_BOUND), so the rule
# picks one only when no other is left, whatever the temperature.
PRIOR_EXCLUDED_M = 2 * FEATURE_BOUND


def path_prior(node_features: torch.Tensor, temperature: float,
               pocket_m: float = 0.0) -> torch.Tensor:
    """Logits of the nearest-node rule from v2 or v3 node features: ``-path / temperature``,
    with unreachable or blacklisted nodes ``PRIOR_EXCLUDED_M`` farther. Its argmax over the
    valid nodes is the frontier node nearest along the known map (what nearest-frontier
    picks). With ``pocket_m`` (v3) a node also counts ``pocket_m`` times its pocket
    probability farther: the nearest frontier whose pocket is not likely small.

    Args:
        node_features: (..., N, F) v2 or v3 node features (raw: metres, flags).
        temperature: Path length per nat, metres (> 0): the prior prefers a node ``t``
            metres nearer by a factor e.
        pocket_m: Metres added per unit of pocket probability (v3 features; 0: none).

    Returns:
        (..., N) logits.
    """
    path = node_features[..., PATH]
    excluded = (node_features[..., UNREACHABLE] + node_features[..., BLACKLISTED]) > 0
    cost = path + PRIOR_EXCLUDED_M * excluded.to(path.dtype)
    if pocket_m:
        cost = cost + pocket_m * node_features[..., POCKET]
    return -cost / temperature


ATTENTION_GROUPS = 4  # Size groups of a batch's global attention (GVN.attend).


def real_positions(real_rows: torch.Tensor, size: int) -> torch.Tensor:
    """(size,) map from a flat slot index to its position among ``real_rows`` (R, their
    count, for padding slots)."""
    r = len(real_rows)
    position = torch.full((size,), r, dtype=torch.long, device=real_rows.device)
    position[real_rows] = torch.arange(r, device=real_rows.device)
    return position


def distinct_graphs(features: torch.Tensor, neighbours: torch.Tensor,
                    node_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The distinct graphs of a batch of padded graphs (graphs with equal arrays are one).

    Graphs with the same node count and first nodes' features (summed into one number)
    are candidates, compared in full with the first of them; those that differ go through
    the same again.

    Args:
        features: (M, N, F) node features.
        neighbours: (M, N, K) neighbour indices.
        node_mask: (M, N) 1 for real nodes.

    Returns:
        (U,) the index of one copy of each distinct graph, ascending, and (M,) the position
        in that list of each graph's copy.
    """
    m = len(node_mask)
    index = torch.arange(m, device=node_mask.device)
    key = torch.cat([node_mask.sum(-1, keepdim=True),
                     features[:, :KEY_NODES].flatten(1)], 1).double()
    # The key as one number (a fixed weighted sum; unique over rows is far slower): equal
    # keys give equal numbers, and unequal graphs that share one are told apart below.
    weights = torch.arange(1, key.shape[1] + 1, dtype=key.dtype, device=key.device).sqrt()
    kind = torch.unique((key * weights).sum(1), return_inverse=True)[1]
    copy_of = index.clone()
    unsettled = index
    while len(unsettled):
        k = kind[unsettled]
        first = torch.full_like(index, m).scatter_reduce(0, k, unsettled, "amin")[k]
        later = first != unsettled
        graph, orig = unsettled[later], first[later]
        same = ((features[graph] == features[orig]).flatten(1).all(1)
                & (neighbours[graph] == neighbours[orig]).flatten(1).all(1)
                & (node_mask[graph] == node_mask[orig]).all(1))
        copy_of[graph[same]] = orig[same]
        unsettled = graph[~same]
    return torch.unique(copy_of, return_inverse=True)


def normalized_adjacency(neighbours: torch.Tensor, real_rows: torch.Tensor) -> torch.Tensor:
    """D^-1/2 (A + I) D^-1/2 of a batch of padded graphs, over their real nodes only.

    Padding nodes take no part (they would only add empty rows and columns), so the matrix
    is one sparse block-diagonal (R, R) over the R real nodes, in the order of
    ``real_rows``. An edge to a padding slot still counts in its node's degree.

    Args:
        neighbours: (M, N, K) neighbour indices within each graph, -1 for empty slots.
        real_rows: (R,) flat indices (graph * N + node) of the real nodes, ascending.

    Returns:
        Sparse (R, R) float tensor in CSR layout (its products are about twice as fast as
        COO's on CPU).
    """
    m, n, k = neighbours.shape
    r = len(real_rows)
    slots = neighbours.reshape(m * n, k)[real_rows].long()  # (R, K)
    edge = slots >= 0
    inv_sqrt = (1.0 + edge.sum(-1).to(torch.float32)).rsqrt()  # Self loop included.
    neighbour_flat = (real_rows // n)[:, None] * n + slots.clamp(min=0)
    target = real_positions(real_rows, m * n)[neighbour_flat]
    # Row i holds its self loop and the nodes it joins (an edge to a padding slot joins
    # nothing), columns ascending; r marks an empty entry and sorts last.
    self_loop = torch.arange(r, device=neighbours.device)[:, None]
    cols = torch.cat([self_loop, torch.where(edge & (target < r), target, r)], 1).sort(1).values
    kept = cols < r
    values = inv_sqrt[:, None] * inv_sqrt[cols.clamp(max=max(r - 1, 0))]
    crow = torch.cat([kept.new_zeros(1, dtype=torch.long), kept.sum(1).cumsum(0)])
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta")
        return torch.sparse_csr_tensor(crow, cols[kept], values[kept], (r, r),
                                       check_invariants=False)


def narrow_linear(h: torch.Tensor, linear: nn.Linear) -> torch.Tensor:
    """``linear(h)`` (no bias) for a narrow input (R, in), in << R.

    Written as h @ W^T with W^T made contiguous: autograd forms the gradient of a row-major
    right factor as h^T G (in, out), several times faster on CPU than the G^T h (out, in)
    it forms for ``F.linear``'s transposed weight.
    """
    return h @ linear.weight.t().contiguous()


class GraphConv(nn.Module):
    """One GCN layer of Eq. 8 before its activation: A_norm H W."""

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.weight = nn.Linear(in_features, out_features, bias=False)

    def forward(self, h: torch.Tensor, adjacency: torch.Tensor) -> torch.Tensor:
        """(R, in) node rows, sparse (R, R) A_norm -> (R, out)."""
        if self.weight.in_features < self.weight.out_features:
            # The sparse product on the narrower side: (A H) W = A (H W).
            return narrow_linear(torch.sparse.mm(adjacency, h), self.weight)
        return torch.sparse.mm(adjacency, self.weight(h))


class SpatialEncoder(nn.Module):
    """E_S: G^{l+1} = ReLU(A_norm G^l W^l) + G^l (a linear projection on the first skip)."""

    scale: torch.Tensor  # Buffers.

    def __init__(self, config: GvnConfig) -> None:
        super().__init__()
        d = config.hidden
        self.register_buffer("scale", torch.tensor(FEATURE_SCALE), persistent=False)
        self.layers = nn.ModuleList(
            GraphConv(NUM_FEATURES if i == 0 else d, d) for i in range(config.gcn_layers))
        self.input_skip = nn.Linear(NUM_FEATURES, d, bias=False)

    def rows(self, features: torch.Tensor, neighbours: torch.Tensor,
             node_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, N, 6), (M, N, K), (M, N) -> embeddings (R, d) of the R real nodes and their
        flat indices (R,) (graph * N + node, ascending).

        Only real nodes are computed: most of the N slots (and every slot of an unfilled
        memory entry) are padding, whose rows and columns of A_norm are empty.
        """
        m, n, _ = features.shape
        real_rows = (node_mask.reshape(-1) > 0).nonzero().squeeze(1)
        adjacency = normalized_adjacency(neighbours, real_rows)
        h = features.reshape(m * n, -1)[real_rows] * self.scale
        for i, layer in enumerate(self.layers):
            skip = narrow_linear(h, self.input_skip) if i == 0 else h
            h = F.relu(layer(h, adjacency)) + skip
        return h, real_rows

    def forward(self, features: torch.Tensor, neighbours: torch.Tensor,
                node_mask: torch.Tensor) -> torch.Tensor:
        """(M, N, F), (M, N, K), (M, N) -> node embeddings (M, N, d), zero on padding."""
        m, n, _ = features.shape
        h, real_rows = self.rows(features, neighbours, node_mask)
        return h.new_zeros(m * n, h.shape[-1]).index_copy(0, real_rows, h).view(m, n, -1)


class _SparseProduct(torch.autograd.Function):
    """A h for a constant sparse A whose transpose is given (the gradient A^T g)."""

    @staticmethod
    def forward(ctx, matrix: torch.Tensor, transposed: torch.Tensor,
                h: torch.Tensor) -> torch.Tensor:
        ctx.transposed = transposed
        return torch.sparse.mm(matrix, h)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[None, None, torch.Tensor]:
        return None, None, torch.sparse.mm(ctx.transposed, grad)


class EdgeMessages:
    """The neighbour messages of one pass of the v2 encoder over R node rows: for rows g
    (R, in), m_ib = mean over i's neighbours j of phi_b(l_ij) g_j, with l_ij the edge
    length and phi_b Gaussians of it (:data:`LENGTH_BASIS`). Built once from the edges
    and applied by every layer of the pass.

    Two forms of the same sums: a sparse (R B, R) matrix of the weights phi_b(l_ij) /
    degree(i) times the rows (one product, no (R, K, in) copy of the neighbours' rows; the
    training form, cheaper to differentiate), and the rows gathered per edge and weighted
    (gathers only: inference and ONNX export). They differ by float rounding only.

    Args:
        target: (R, K) 1-based neighbour rows, 0 for no neighbour.
        lengths: (R, K) edge lengths, metres.
        centres: (B,) Gaussian centres, metres.
        widths: (B,) Gaussian widths, metres.
        sparse: Use the sparse form (else the gathered one).
    """

    def __init__(self, target: torch.Tensor, lengths: torch.Tensor, centres: torch.Tensor,
                 widths: torch.Tensor, sparse: bool) -> None:
        self.target = target
        edge = (target > 0).to(lengths.dtype)
        basis = torch.exp(-((lengths[..., None] - centres) / widths).square())
        self.weights = basis * (edge / edge.sum(1, keepdim=True).clamp(min=1.0))[..., None]
        self.matrix = self.transposed = None
        if sparse:
            self.matrix, self.transposed = self._matrices()

    def _matrices(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The sparse (R B, R) CSR matrix, row i B + b holding phi_b(l_ij) / degree(i) at
        column j for each neighbour j of i (columns ascending), and its (R, R B) transpose
        (the gradient's product, made once for every layer)."""
        r, k = self.target.shape
        b = self.weights.shape[-1]
        real = self.target > 0
        column = torch.where(real, self.target - 1, r)
        order = column.argsort(1)  # Empty slots (column r) last.
        column, real = column.gather(1, order), real.gather(1, order)
        weights = self.weights.gather(1, order[..., None].expand_as(self.weights))
        per_row = real.sum(1).repeat_interleave(b)
        crow = torch.cat([per_row.new_zeros(1), per_row.cumsum(0)])
        entries = real[:, None, :].expand(r, b, k)
        column = column[:, None, :].expand(r, b, k)[entries]
        values = weights.transpose(1, 2)[entries]
        # The transpose: the same entries ordered by column, rows ascending within each.
        by_column = column.argsort(stable=True)
        row = torch.repeat_interleave(torch.arange(r * b, device=crow.device), per_row)
        per_column = torch.bincount(column, minlength=r)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta")
            return (torch.sparse_csr_tensor(crow, column, values, (r * b, r),
                                            check_invariants=False),
                    torch.sparse_csr_tensor(
                        torch.cat([per_column.new_zeros(1), per_column.cumsum(0)]),
                        row[by_column], values[by_column], (r, r * b),
                        check_invariants=False))

    def __call__(self, h: torch.Tensor) -> torch.Tensor:
        """(R, in) node rows -> (R, B in) messages, m_ib at column b in + i."""
        r = len(self.target)
        if self.matrix is not None:
            return _SparseProduct.apply(self.matrix, self.transposed, h).view(r, -1)
        # index_select rather than indexing: its backward (index_add) is the cheaper one.
        neighbours = torch.cat([h.new_zeros(1, h.shape[-1]), h]).index_select(
            0, self.target.reshape(-1)).view(r, self.target.shape[1], -1)  # (R, K, in)
        return torch.einsum("rkb,rki->rbi", self.weights, neighbours).reshape(r, -1)


class LengthConv(nn.Module):
    """One v2 message-passing layer before its activation: W_s g_i + sum_b W_b m_ib, with
    m_ib = mean over i's neighbours j of phi_b(l_ij) g_j, l_ij the edge length and phi_b
    Gaussians of it (:data:`LENGTH_BASIS`, :class:`EdgeMessages`): a continuous filter of
    the edge length, so that each output channel has its own learned response to short
    and long edges."""

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.self_weight = nn.Linear(in_features, out_features)
        self.neighbour_weight = nn.Linear(len(LENGTH_BASIS[0]) * in_features, out_features,
                                          bias=False)

    def forward(self, h: torch.Tensor, messages: EdgeMessages) -> torch.Tensor:
        """(R, in) node rows and their pass's messages -> (R, out)."""
        return self.self_weight(h) + self.neighbour_weight(messages(h))


class EdgeSpatialEncoder(SpatialEncoder):
    """v2 E_S: G^{l+1} = ReLU(LengthConv(G^l)) + G^l (a linear projection on the first
    skip); :class:`SpatialEncoder`'s interface and ``forward``.

    Written with gathers only, and with no tensor filled with a value that depends on the
    data (a real node's row is a running count), so that it exports to ONNX as it is.
    """

    centres: torch.Tensor  # Buffers.
    widths: torch.Tensor

    def __init__(self, config: GvnConfig, num_features: int) -> None:
        nn.Module.__init__(self)  # Not SpatialEncoder's layers.
        d = config.hidden
        self.register_buffer("scale", torch.tensor(FEATURE_SCALE_V2[:num_features]),
                             persistent=False)
        self.register_buffer("centres", torch.tensor(LENGTH_BASIS[0]), persistent=False)
        self.register_buffer("widths", torch.tensor(LENGTH_BASIS[1]), persistent=False)
        self.layers = nn.ModuleList(LengthConv(num_features if i == 0 else d, d)
                                    for i in range(config.gcn_layers))
        self.input_skip = nn.Linear(num_features, d, bias=False)

    def rows(self, features: torch.Tensor, neighbours: torch.Tensor,
             node_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, N, F), (M, N, K), (M, N) -> embeddings (R, d) of the R real nodes and their
        flat indices (R,) (graph * N + node, ascending)."""
        m, n, k = neighbours.shape
        real = node_mask.reshape(m * n) > 0
        real_rows = real.nonzero().squeeze(1)
        # 1-based place of each slot among the real rows, 0 for padding.
        place = torch.where(real, real.long().cumsum(0), torch.zeros((), dtype=torch.long))
        slots = neighbours.reshape(m * n, k).index_select(0, real_rows).long()
        target = place[((real_rows // n)[:, None] * n + slots.clamp(min=0)).reshape(-1)]
        target = torch.where(slots >= 0, target.reshape(-1, k),
                             torch.zeros((), dtype=torch.long))
        raw = features.reshape(m * n, -1).index_select(0, real_rows)
        xy = raw[:, :2]
        lengths = torch.linalg.vector_norm(
            xy[:, None] - torch.cat([xy.new_zeros(1, 2), xy])[target], dim=-1)
        # The sparse form where gradients are taken (PPO's update); inference keeps the
        # gathered one, so that a policy acts on the very numbers it always did.
        messages = EdgeMessages(target, lengths, self.centres, self.widths,
                                sparse=torch.is_grad_enabled() and not tracing())
        h = raw * self.scale
        for i, layer in enumerate(self.layers):
            skip = self.input_skip(h) if i == 0 else h
            h = F.relu(layer(h, messages)) + skip
        return h, real_rows



class GlobalAttention(nn.Module):
    """A pre-norm transformer encoder layer over a padded set of tokens (no positional
    encoding: nodes carry their positions in their features)."""

    def __init__(self, d: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.norm1 = nn.LayerNorm(d)
        self.qkv = nn.Linear(d, 3 * d)
        self.out = nn.Linear(d, d)
        self.norm2 = nn.LayerNorm(d)
        self.feedforward = nn.Sequential(nn.Linear(d, 2 * d), nn.ReLU(), nn.Linear(2 * d, d))

    def forward(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """(B, T, d) tokens, (B, T) bool True for real tokens (at least one per row) ->
        (B, T, d); padding tokens attend but are attended by none."""
        b, t, d = x.shape
        q, k, v = (y.view(b, t, self.heads, d // self.heads).transpose(1, 2)
                   for y in self.qkv(self.norm1(x)).chunk(3, -1))
        attended = F.scaled_dot_product_attention(q, k, v, attn_mask=valid[:, None, None, :])
        x = x + self.out(attended.transpose(1, 2).reshape(b, t, d))
        return x + self.feedforward(self.norm2(x))


def memory_pose_features(memory_pose: torch.Tensor, memory_features: torch.Tensor,
                         choice: torch.Tensor) -> torch.Tensor:
    """The v2 fragments' place inputs (..., E, 6): the stored pose in the current robot
    frame (dx, dy scaled, cos dyaw, sin dyaw) and the chosen node's position in the current
    frame (scaled).

    Args:
        memory_pose: (..., E, 3) (dx, dy, dyaw) of the stored poses in the current frame.
        memory_features: (..., E, N, F) the remembered TERs' node features.
        choice: (..., E) the node chosen on each.
    """
    n = memory_features.shape[-2]
    index = choice.long().clamp(0, n - 1)[..., None, None].expand(
        *choice.shape, 1, 2)
    px, py = torch.gather(memory_features[..., :2], -2, index)[..., 0, :].unbind(-1)
    dx, dy, dyaw = memory_pose.unbind(-1)
    c, s = torch.cos(dyaw), torch.sin(dyaw)
    return torch.stack([dx * METRES_SCALE, dy * METRES_SCALE, c, s,
                        (c * px - s * py + dx) * METRES_SCALE,
                        (s * px + c * py + dy) * METRES_SCALE], -1)


class CausalConv(nn.Module):
    """One dilated causal 1-D convolution (Eq. 9): out_t = sum_k eta_k m_{t-(K-k) d}."""

    def __init__(self, channels: int, kernel: int, dilation: int) -> None:
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv = nn.Conv1d(channels, channels, kernel, dilation=dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, T) -> (B, C, T); output t sees inputs <= t only."""
        return self.conv(F.pad(x, (self.pad, 0)))


class TemporalEncoder(nn.Module):
    """E_T: residual stack of dilated causal convolutions over the memory fragments."""

    def __init__(self, config: GvnConfig) -> None:
        super().__init__()
        self.layers = nn.ModuleList(CausalConv(config.hidden, config.tcn_kernel, d)
                                    for d in config.tcn_dilations)

    def forward(self, fragments: torch.Tensor) -> torch.Tensor:
        """(B, T, d) fragments, oldest first -> (B, T, d) outputs (causal)."""
        x = fragments.transpose(1, 2)
        for layer in self.layers:
            x = F.relu(layer(x)) + x
        return x.transpose(1, 2)


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of (..., N, d) over the N axis where ``mask`` (..., N) is 1."""
    return (x * mask[..., None]).sum(-2) / mask.sum(-1, keepdim=True).clamp(min=1.0)


class EncodedTers:
    """The node embeddings of recently encoded TERs, for inference without gradients.

    Deciding, a policy re-encodes each TER of its memory at every one of the next E
    decisions; with this it encodes each once while its weights stay the same. An entry
    is found by the TER's arrays themselves (exact: equal arrays, as in
    :func:`distinct_graphs`), and all entries are dropped when any weight of the encoder
    changes (an optimizer step or a load bumps the tensors' version counters).

    Args:
        capacity: Entries kept, least recently used dropped first.
    """

    def __init__(self, capacity: int = 512) -> None:
        self.capacity = capacity
        self.entries: OrderedDict[bytes, torch.Tensor] = OrderedDict()
        self.weights_version: tuple = ()

    def rows(self, encoder: SpatialEncoder, features: torch.Tensor, neighbours: torch.Tensor,
             node_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``encoder.rows`` (see :meth:`SpatialEncoder.rows`), encoding only the TERs not
        held: (M, N, F), (M, N, K), (M, N) -> (R, d) embeddings, (R,) flat indices."""
        version = tuple((p.data_ptr(), p._version) for p in encoder.parameters())
        if version != self.weights_version:
            self.entries.clear()
            self.weights_version = version
        arrays = [a.detach().cpu().numpy() for a in (features, neighbours, node_mask)]
        keys = [b"".join(a[i].tobytes() for a in arrays) for i in range(len(node_mask))]
        missing = [i for i, key in enumerate(keys) if key not in self.entries]
        if missing:
            index = torch.tensor(missing, device=node_mask.device)
            encoded, _ = encoder.rows(features[index], neighbours[index], node_mask[index])
            counts = (node_mask[index] > 0).sum(1).tolist()
            for i, part in zip(missing, encoded.split(counts)):
                self.entries[keys[i]] = part
        rows = torch.cat([self.entries[key] for key in keys])
        for key in keys:
            self.entries.move_to_end(key)
        while len(self.entries) > self.capacity:
            self.entries.popitem(last=False)
        return rows, (node_mask.reshape(-1) > 0).nonzero().squeeze(1)


def tracing() -> bool:
    """Whether torch is tracing or compiling the code (an ONNX export): code paths with
    data-dependent shapes or sparse tensors are left for plain ones then."""
    return (torch.jit.is_tracing() or torch.compiler.is_compiling()
            or torch.onnx.is_in_onnx_export())


class GVN(nn.Module):
    """Spatial encoder, episodic memory, attention fusion and aggregator (no heads).

    ``forward`` takes the observation dict (batched torch tensors) and returns the node
    features z (B, N, d) and a graph summary (B, 2d) for the critic.

    Args:
        config: Sizes and the feature set ('v1': the paper's network; 'v2': see the module
            docstring).
        num_features: F, node features per node of the observation (6 for v1, 9 for v2).
    """

    def __init__(self, config: GvnConfig | None = None, num_features: int | None = None) -> None:
        super().__init__()
        self.config = config = config or GvnConfig()
        d = config.hidden
        if config.features == "v1":
            self.spatial = SpatialEncoder(config)
            self.fragment = nn.Linear(2 * d, d)
        else:
            self.spatial = EdgeSpatialEncoder(config, num_features or len(FEATURE_SCALE_V2))
            self.fragment = nn.Linear(2 * d + POSE_FEATURES, d)
            self.global_attention = nn.ModuleList(
                GlobalAttention(d, config.attention_heads)
                for _ in range(config.attention_layers))
        self.temporal = TemporalEncoder(config)
        self.encoded = EncodedTers()
        self.attention = nn.Linear(d, 1)
        self.aggregator = nn.Sequential(nn.Linear(2 * d, d), nn.ReLU(), nn.Linear(d, d), nn.ReLU())

    def fragments(self, rows: torch.Tensor, real_rows: torch.Tensor, node_mask: torch.Tensor,
                  choice: torch.Tensor, graph: torch.Tensor | None = None,
                  place: torch.Tensor | None = None) -> torch.Tensor:
        """Memory fragments (F, d): the mean node embedding of a remembered TER beside the
        embedding of the node chosen on it (and, v2, where it was stored).

        Args:
            rows: (R, d) embeddings of the real nodes of M TERs (:meth:`SpatialEncoder.rows`).
            real_rows: (R,) their flat indices, graph * N + node.
            node_mask: (M, N) 1 for real nodes.
            choice: (F,) the node chosen on each remembered TER (a padding node gives zeros).
            graph: (F,) which of the M TERs each fragment is of (default: fragment i of TER
                i, F = M).
            place: v2: (F, 6) :func:`memory_pose_features` of each fragment.
        """
        m, n = node_mask.shape
        d = rows.shape[-1]
        if graph is None:
            graph = torch.arange(m, device=rows.device)
        mean = (rows.new_zeros(m, d).index_add(0, real_rows // n, rows)
                / node_mask.sum(-1, keepdim=True).clamp(min=1.0))
        chosen_flat = graph * n + choice.long().clamp(0, n - 1)
        chosen = torch.cat([rows, rows.new_zeros(1, d)]).index_select(
            0, real_positions(real_rows, m * n)[chosen_flat])
        inputs = [mean.index_select(0, graph), chosen] + ([] if place is None else [place])
        return self.fragment(torch.cat(inputs, -1))

    def memory_from_fragments(self, fragments: torch.Tensor,
                              memory_mask: torch.Tensor) -> torch.Tensor:
        """h^M (B, d) from fragments (B, E, d), oldest first, and their mask (B, E)."""
        return self.temporal(fragments * memory_mask[..., None])[:, -1]

    def encode(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor,
                                                             torch.Tensor]:
        """Encodes the TERs of a batch of (structured) observations, each distinct one once.

        A PPO minibatch holds each TER many times: as the current TER of its decision and in
        the memory of the next E decisions of its episode. The encoder runs on the distinct
        TERs only (see :func:`distinct_graphs`) and its outputs are gathered back, which
        gives the same numbers as encoding every copy. Without gradients, TERs encoded by
        earlier calls with the same weights are taken from :class:`EncodedTers`.

        Returns:
            The embeddings (R, d) of the real nodes of the current TERs, their flat indices
            (R,) (sample * N + node, ascending), and the memory fragments (B, E, d).
        """
        b, e, n = obs["memory_node_mask"].shape
        # Graph g = sample * (E + 1) + slot; slot 0 is the current TER, 1 + j memory slot j.
        features, neighbours, node_mask = (
            torch.cat([obs[key][:, None], obs[f"memory_{key}"]], 1).flatten(0, 1)
            for key in ("node_features", "neighbours", "node_mask"))
        keep, inverse = distinct_graphs(features, neighbours, node_mask)
        node_mask = node_mask[keep]
        if torch.is_grad_enabled() or tracing():
            rows, real_rows = self.spatial.rows(features[keep], neighbours[keep], node_mask)
        else:
            rows, real_rows = self.encoded.rows(self.spatial, features[keep], neighbours[keep],
                                                node_mask)
        inverse = inverse.view(b, e + 1)
        current_rows = (obs["node_mask"].reshape(-1) > 0).nonzero().squeeze(1)
        # A current TER's real nodes are those of its distinct copy (equal arrays).
        copy_rows = inverse[:, 0][current_rows // n] * n + current_rows % n
        current = rows.index_select(0, real_positions(real_rows, len(keep) * n)[copy_rows])
        place = None
        if self.config.features == "v2":
            place = memory_pose_features(obs["memory_pose"], obs["memory_node_features"],
                                         obs["memory_choice"]).reshape(b * e, -1)
        fragments = self.fragments(rows, real_rows, node_mask,
                                   obs["memory_choice"].reshape(b * e),
                                   graph=inverse[:, 1:].reshape(b * e), place=place)
        return current, current_rows, fragments.view(b, e, -1)

    def node_outputs(self, r: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """Attention fusion and aggregator of node embeddings r (..., d) with the memory h
        (..., d) beside each: node features z (..., d) (Eq. 10-12)."""
        scores = torch.cat([self.attention(r), self.attention(h)], -1)  # Eq. 11.
        alpha = torch.softmax(scores, -1)
        fused = alpha[..., :1] * r + alpha[..., 1:] * h  # Eq. 10.
        return self.aggregator(torch.cat([fused, r], -1))  # Eq. 12.

    @staticmethod
    def pool(z: torch.Tensor, node_mask: torch.Tensor) -> torch.Tensor:
        """The critic's graph summary (B, 2d): masked mean and max of z (B, N, d)."""
        pooled_max = z.masked_fill(node_mask[..., None] <= 0, -1e4).amax(-2)
        pooled_max = torch.where(node_mask.sum(-1, keepdim=True) > 0, pooled_max, 0.0)
        return torch.cat([masked_mean(z, node_mask), pooled_max], -1)

    def fuse(self, r: torch.Tensor, node_mask: torch.Tensor,
             h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Node features z (B, N, d), zero on padding, and the critic's graph summary
        (B, 2d) from embeddings r (B, N, d) and memory h (B, d)."""
        z = self.node_outputs(r, h[:, None].expand_as(r)) * node_mask[..., None]
        return z, self.pool(z, node_mask)

    def fuse_rows(self, rows: torch.Tensor, real_rows: torch.Tensor, node_mask: torch.Tensor,
                  h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`fuse` computed on the real nodes only: embeddings rows (R, d) at flat
        indices real_rows (R,) (sample * N + node) of a batch with node_mask (B, N)."""
        b, n = node_mask.shape
        d = rows.shape[-1]
        sample = real_rows // n
        z = self.node_outputs(rows, h.index_select(0, sample))
        mean = (rows.new_zeros(b, d).index_add(0, sample, z)
                / node_mask.sum(-1, keepdim=True).clamp(min=1.0))
        # A graph without real nodes keeps the zeros it starts with (as in pool).
        pooled_max = rows.new_zeros(b, d).scatter_reduce(
            0, sample[:, None].expand_as(z), z, "amax", include_self=False)
        dense = rows.new_zeros(b * n, d).index_copy(0, real_rows, z).view(b, n, d)
        return dense, torch.cat([mean, pooled_max], -1)

    def attend_dense(self, r: torch.Tensor, valid: torch.Tensor,
                     h: torch.Tensor) -> torch.Tensor:
        """v2: the global attention layers over node embeddings r (B, W, d) (``valid`` (B, W)
        True for real nodes) and the memory summary h (B, d) as a token of its own
        -> (B, W, d)."""
        tokens = torch.cat([h[:, None], r], 1)
        valid = torch.cat([torch.ones_like(valid[:, :1]), valid], 1)
        for layer in self.global_attention:
            tokens = layer(tokens, valid)
        return tokens[:, 1:]

    def attend(self, rows: torch.Tensor, real_rows: torch.Tensor, node_mask: torch.Tensor,
               h: torch.Tensor) -> torch.Tensor:
        """:meth:`attend_dense` for rows (R, d) at flat indices real_rows (R,) (sample * N +
        node) of a batch with node_mask (B, N) -> rows (R, d).

        The samples go through in groups of similar size (:data:`ATTENTION_GROUPS`, by their
        node count), each group's dense arrays cut after its last real node (padding trails
        the real nodes in a padded TER): attention's cost grows with the square of the
        width, and a batch's TERs range from a few nodes to a few hundred.
        """
        b, n = node_mask.shape
        sample, node = real_rows // n, real_rows % n
        d = rows.shape[-1]
        count = torch.zeros(b, dtype=torch.long, device=rows.device).scatter_reduce(
            0, sample, node + 1, "amax")
        by_size = torch.argsort(count, stable=True)
        groups = [members.sort().values for members in torch.tensor_split(
            by_size, max(min(ATTENTION_GROUPS, b), 1)) if len(members)]
        group = torch.empty(b, dtype=torch.long, device=rows.device)
        place = torch.empty(b, dtype=torch.long, device=rows.device)
        for g, members in enumerate(groups):
            group[members] = g
            place[members] = torch.arange(len(members), device=rows.device)
        # The rows ordered by group (then as they were): each group's are one run.
        by_group = torch.argsort(group[sample] * (b * n) + real_rows)
        sizes = torch.bincount(group[sample], minlength=len(groups)).tolist()
        out = []
        for members, picked in zip(groups, torch.split(by_group, sizes)):
            width = int(count[members].max())
            if width == 0:
                continue  # Samples without nodes: no rows to attend.
            flat = place[sample[picked]] * width + node[picked]
            dense = rows.new_zeros(len(members) * width, d).index_copy(
                0, flat, rows.index_select(0, picked)).view(len(members), width, d)
            valid = torch.zeros(len(members) * width, dtype=torch.bool,
                                device=rows.device).index_fill(0, flat, True)
            attended = self.attend_dense(dense, valid.view(len(members), width),
                                         h.index_select(0, members))
            out.append(attended.reshape(-1, d).index_select(0, flat))
        if not out:
            return rows.new_zeros(rows.shape)
        return rows.new_zeros(rows.shape).index_copy(0, by_group, torch.cat(out))

    def forward(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched flat observations (see :mod:`mjexplore.envs.observation`) -> (z, pooled)."""
        obs = structured(obs)
        rows, real_rows, fragments = self.encode(obs)
        h = self.memory_from_fragments(fragments, obs["memory_mask"])
        if self.config.features == "v2":
            rows = self.attend(rows, real_rows, obs["node_mask"], h)
        return self.fuse_rows(rows, real_rows, obs["node_mask"], h)
