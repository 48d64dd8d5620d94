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
"""

from __future__ import annotations

import dataclasses
import warnings

import torch
from torch import nn
from torch.nn import functional as F

from mjexplore.envs.observation import structured
from mjexplore.topology.ter import NUM_FEATURES

# Fixed input scaling of [px, py, G_info, phi_diff, D, flag]: metres / 10, radians / pi.
FEATURE_SCALE = (0.1, 0.1, 1.0, 1.0 / torch.pi, 0.1, 1.0)
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
    """

    hidden: int = 64
    gcn_layers: int = 3
    tcn_kernel: int = 3
    tcn_dilations: tuple[int, ...] = (1, 2, 4)


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

    Graphs with the same node count and first nodes' features are candidates, compared in
    full with the first of them; those that differ go through the same again.

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
                     features[:, :KEY_NODES].flatten(1)], 1)
    kind = torch.unique(key, dim=0, return_inverse=True)[1]
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
        """(M, N, 6), (M, N, K), (M, N) -> node embeddings (M, N, d), zero on padding."""
        m, n, _ = features.shape
        h, real_rows = self.rows(features, neighbours, node_mask)
        return h.new_zeros(m * n, h.shape[-1]).index_copy(0, real_rows, h).view(m, n, -1)


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


class GVN(nn.Module):
    """Spatial encoder, episodic memory, attention fusion and aggregator (no heads).

    ``forward`` takes the observation dict (batched torch tensors) and returns the node
    features z (B, N, d) and a graph summary (B, 2d) for the critic.
    """

    def __init__(self, config: GvnConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or GvnConfig()
        d = config.hidden
        self.spatial = SpatialEncoder(config)
        self.fragment = nn.Linear(2 * d, d)
        self.temporal = TemporalEncoder(config)
        self.attention = nn.Linear(d, 1)
        self.aggregator = nn.Sequential(nn.Linear(2 * d, d), nn.ReLU(), nn.Linear(d, d), nn.ReLU())

    def fragments(self, rows: torch.Tensor, real_rows: torch.Tensor, node_mask: torch.Tensor,
                  choice: torch.Tensor, graph: torch.Tensor | None = None) -> torch.Tensor:
        """Memory fragments (F, d): the mean node embedding of a remembered TER beside the
        embedding of the node chosen on it.

        Args:
            rows: (R, d) embeddings of the real nodes of M TERs (:meth:`SpatialEncoder.rows`).
            real_rows: (R,) their flat indices, graph * N + node.
            node_mask: (M, N) 1 for real nodes.
            choice: (F,) the node chosen on each remembered TER (a padding node gives zeros).
            graph: (F,) which of the M TERs each fragment is of (default: fragment i of TER
                i, F = M).
        """
        m, n = node_mask.shape
        d = rows.shape[-1]
        if graph is None:
            graph = torch.arange(m, device=rows.device)
        mean = (rows.new_zeros(m, d).index_add(0, real_rows // n, rows)
                / node_mask.sum(-1, keepdim=True).clamp(min=1.0))
        chosen_flat = graph * n + choice.long().clamp(0, n - 1)
        chosen = torch.cat([rows, rows.new_zeros(1, d)])[real_positions(real_rows, m * n)
                                                         [chosen_flat]]
        return self.fragment(torch.cat([mean[graph], chosen], -1))

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
        gives the same numbers as encoding every copy.

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
        rows, real_rows = self.spatial.rows(features[keep], neighbours[keep], node_mask)
        inverse = inverse.view(b, e + 1)
        current_rows = (obs["node_mask"].reshape(-1) > 0).nonzero().squeeze(1)
        # A current TER's real nodes are those of its distinct copy (equal arrays).
        copy_rows = inverse[:, 0][current_rows // n] * n + current_rows % n
        current = rows[real_positions(real_rows, len(keep) * n)[copy_rows]]
        fragments = self.fragments(rows, real_rows, node_mask,
                                   obs["memory_choice"].reshape(b * e),
                                   graph=inverse[:, 1:].reshape(b * e))
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
        z = self.node_outputs(rows, h[sample])
        mean = (rows.new_zeros(b, d).index_add(0, sample, z)
                / node_mask.sum(-1, keepdim=True).clamp(min=1.0))
        # A graph without real nodes keeps the zeros it starts with (as in pool).
        pooled_max = rows.new_zeros(b, d).scatter_reduce(
            0, sample[:, None].expand_as(z), z, "amax", include_self=False)
        dense = rows.new_zeros(b * n, d).index_copy(0, real_rows, z).view(b, n, d)
        return dense, torch.cat([mean, pooled_max], -1)

    def forward(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched flat observations (see :mod:`mjexplore.envs.observation`) -> (z, pooled)."""
        obs = structured(obs)
        rows, real_rows, fragments = self.encode(obs)
        return self.fuse_rows(rows, real_rows, obs["node_mask"],
                              self.memory_from_fragments(fragments, obs["memory_mask"]))
