"""The Generalized Voronoi Network (GVN) of the EMExplorer paper, in plain torch.

Pipeline for one decision (paper Fig. 3), B observations of N TER nodes:

1. Spatial encoder E_S: a 3-layer GCN with symmetric normalisation and residual
   connections (Eq. 8) turns the node features into node embeddings r^G (B, N, d).
2. Episodic memory: each of the last epsilon decisions is re-encoded by the same E_S from
   its TER (carried raw in the observation, see :mod:`mjexplore.envs.observation`); its
   memory fragment is the mean node embedding of that TER joined with the embedding of the
   node chosen then (the "frontier feature").
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

import torch
from torch import nn
from torch.nn import functional as F

from mjexplore.envs.observation import structured
from mjexplore.topology.ter import NUM_FEATURES

# Fixed input scaling of [px, py, G_info, phi_diff, D, flag]: metres / 10, radians / pi.
FEATURE_SCALE = (0.1, 0.1, 1.0, 1.0 / torch.pi, 0.1, 1.0)


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


def normalized_adjacency(neighbours: torch.Tensor, real_rows: torch.Tensor) -> torch.Tensor:
    """D^-1/2 (A + I) D^-1/2 of a batch of padded graphs, over their real nodes only.

    Padding nodes take no part (they would only add empty rows and columns), so the matrix
    is one sparse block-diagonal (R, R) over the R real nodes, in the order of
    ``real_rows``. An edge to a padding slot still counts in its node's degree.

    Args:
        neighbours: (M, N, K) neighbour indices within each graph, -1 for empty slots.
        real_rows: (R,) flat indices (graph * N + node) of the real nodes, ascending.

    Returns:
        Sparse (R, R) float tensor.
    """
    m, n, k = neighbours.shape
    device = neighbours.device
    r = len(real_rows)
    slots = neighbours.reshape(m * n, k)[real_rows].long()  # (R, K)
    edge = slots >= 0
    inv_sqrt = (1.0 + edge.sum(-1).to(torch.float32)).rsqrt()  # Self loop included.
    neighbour_flat = (real_rows // n)[:, None] * n + slots.clamp(min=0)
    target = real_positions(real_rows, m * n)[neighbour_flat]
    kept = edge & (target < r)  # An edge to a padding slot joins nothing.
    rows = torch.arange(r, device=device)[:, None].expand(r, k)[kept]
    cols = target[kept]
    self_idx = torch.arange(r, device=device)
    indices = torch.cat([torch.stack([rows, cols]), torch.stack([self_idx, self_idx])], dim=1)
    values = torch.cat([inv_sqrt[rows] * inv_sqrt[cols], inv_sqrt.square()])
    return torch.sparse_coo_tensor(indices, values, (r, r), check_invariants=False).coalesce()


class GraphConv(nn.Module):
    """One GCN layer of Eq. 8 before its activation: A_norm H W."""

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.weight = nn.Linear(in_features, out_features, bias=False)

    def forward(self, h: torch.Tensor, adjacency: torch.Tensor) -> torch.Tensor:
        """(R, in) node rows, sparse (R, R) A_norm -> (R, out)."""
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
            skip = self.input_skip(h) if i == 0 else h
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
                  choice: torch.Tensor) -> torch.Tensor:
        """Memory fragments (M, d) of M remembered TERs: the mean of their node embeddings
        beside the embedding of the node chosen on each.

        Args:
            rows: (R, d) embeddings of the real nodes (:meth:`SpatialEncoder.rows`).
            real_rows: (R,) their flat indices, graph * N + node.
            node_mask: (M, N) 1 for real nodes.
            choice: (M,) the node chosen on each TER (a padding node gives zeros).
        """
        m, n = node_mask.shape
        d = rows.shape[-1]
        mean = (rows.new_zeros(m, d).index_add(0, real_rows // n, rows)
                / node_mask.sum(-1, keepdim=True).clamp(min=1.0))
        chosen_flat = torch.arange(m, device=rows.device) * n + choice.long().clamp(0, n - 1)
        chosen = torch.cat([rows, rows.new_zeros(1, d)])[real_positions(real_rows, m * n)
                                                         [chosen_flat]]
        return self.fragment(torch.cat([mean, chosen], -1))

    def memory_from_fragments(self, fragments: torch.Tensor,
                              memory_mask: torch.Tensor) -> torch.Tensor:
        """h^M (B, d) from fragments (B, E, d), oldest first, and their mask (B, E)."""
        return self.temporal(fragments * memory_mask[..., None])[:, -1]

    def memory(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """h^M (B, d), re-encoding the remembered TERs carried in the (structured)
        observation."""
        b, e, n = obs["memory_node_mask"].shape
        node_mask = obs["memory_node_mask"].reshape(b * e, n)
        rows, real_rows = self.spatial.rows(obs["memory_node_features"].reshape(b * e, n, -1),
                                            obs["memory_neighbours"].reshape(b * e, n, -1),
                                            node_mask)
        frag = self.fragments(rows, real_rows, node_mask,
                              obs["memory_choice"].reshape(b * e)).view(b, e, -1)
        return self.memory_from_fragments(frag, obs["memory_mask"])

    def fuse(self, r: torch.Tensor, node_mask: torch.Tensor,
             h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Attention fusion and aggregator: node features z (B, N, d) and the critic's
        graph summary (B, 2d) from embeddings r (B, N, d) and memory h (B, d)."""
        h = h[:, None].expand_as(r)
        scores = torch.cat([self.attention(r), self.attention(h)], -1)  # Eq. 11.
        alpha = torch.softmax(scores, -1)
        fused = alpha[..., :1] * r + alpha[..., 1:] * h  # Eq. 10.
        mask = node_mask[..., None]
        z = self.aggregator(torch.cat([fused, r], -1)) * mask  # Eq. 12.
        pooled_max = z.masked_fill(mask <= 0, -1e4).amax(-2)
        pooled_max = torch.where(node_mask.sum(-1, keepdim=True) > 0, pooled_max, 0.0)
        return z, torch.cat([masked_mean(z, node_mask), pooled_max], -1)

    def forward(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched flat observations (see :mod:`mjexplore.envs.observation`) -> (z, pooled)."""
        obs = structured(obs)
        mask = obs["node_mask"]
        r = self.spatial(obs["node_features"], obs["neighbours"], mask)
        return self.fuse(r, mask, self.memory(obs))
