"""The NDF's encoder network f(P) = z: a VN-PointNet with a local first layer, built from
vector-neuron layers (`ndfa.ndf.vn`), so z rotates with the input points."""

from __future__ import annotations

import torch
from torch import nn

from ndfa.ndf.config import NDFConfig
from ndfa.ndf.vn import VNEdgeConv, VNLinear, VNResnetBlock, vn_max_pool, vn_mean_pool


def knn_edge_features(points: torch.Tensor, k: int) -> torch.Tensor:
    """Equivariant local features of each point's k nearest neighbours (itself included).

    points: `[B, N, 3]`. Returns `[B, N, k, 3, 3]`: per edge (i, j) the three vectors
    [p_i, p_j - p_i, p_i x p_j], each rotating with the input (the cross product does too, for
    proper rotations). The neighbour set itself is rotation-invariant (distances are).
    """
    k = min(k, points.shape[1])
    with torch.no_grad():  # the choice of neighbours needs no gradient
        # |p_i - p_j|^2 = |p_i|^2 + |p_j|^2 - 2 p_i.p_j; the first term is the same along a row, so it
        # does not change the ranking and is left out, as is the square root (one fused op, ~3x cdist).
        norm_sq = (points * points).sum(-1).unsqueeze(-2)  # [B, 1, N]
        ranking = torch.baddbmm(norm_sq, points, points.transpose(-1, -2), alpha=-2.0)  # [B, N, N]
        neighbour_index = ranking.topk(k, largest=False).indices  # [B, N, k]
    batch_index = torch.arange(points.shape[0], device=points.device)[:, None, None]
    neighbours = points[batch_index, neighbour_index]  # [B, N, k, 3]
    centre = points.unsqueeze(2).expand_as(neighbours)
    cross = torch.linalg.cross(centre, neighbours, dim=-1)
    return torch.stack([centre, neighbours - centre, cross], dim=-1)


class VNPool(nn.Module):
    """Pool per-point vector features over the points, `[B, N, 3, C] -> [B, 3, C]`."""

    def __init__(self, c: int, kind: str) -> None:
        super().__init__()
        self.direction = VNLinear(c, c) if kind == "max" else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.direction is None:
            return vn_mean_pool(x)
        return vn_max_pool(x, self.direction(x))


class Encoder(nn.Module):
    """VN-PointNet with a local first layer: `[B, N, 3]` (scaled) -> `[B, 3, latent]`.

    1. Local: a VN layer on each point's k-NN edge features, averaged over the neighbours.
    2. Global: residual VN blocks; before each, a linear map of the features pooled over the whole
       cloud is added to every point, so every point sees the object. (NDF concatenates the
       pooled features instead; adding a linear map of them is what the block's first linear
       layer would make of the concatenation anyway, at half the width.)
    3. Pool over points and map linearly to the `latent` vectors of z.

    With the up cue, world up `[B, 3, 1]` enters every point's features after the local layer
    through a VN-linear map (it rotates with the points). The view ray does not enter here: it is
    the same for all mugs seen from one side, and in a 600-step run where it did, the shape codes
    learnt the viewpoint (validation AUC 0.50, chance); `NDFModel.encode` appends it to z instead.
    """

    def __init__(self, config: NDFConfig) -> None:
        super().__init__()
        h, blocks = config.hidden, config.encoder_blocks
        self.knn = config.knn
        self.local = VNEdgeConv(3, h)
        self.context_pools = nn.ModuleList(VNPool(h, config.pooling) for _ in range(blocks))
        self.context_linears = nn.ModuleList(VNLinear(h, h) for _ in range(blocks))
        self.blocks = nn.ModuleList(VNResnetBlock(h, h) for _ in range(blocks))
        self.final_pool = VNPool(h, config.pooling)
        self.to_latent = VNLinear(h, config.latent - config.cues)  # the cues complete z (NDFModel.encode)
        self.up_in = VNLinear(1, h) if config.up_cue else None

    def forward(self, points: torch.Tensor, up: torch.Tensor | None = None) -> torch.Tensor:
        x = self.local(knn_edge_features(points, self.knn))  # [B, N, 3, h]
        if self.up_in is not None:
            x = x + self.up_in(up).unsqueeze(1)
        for pool, context_linear, block in zip(self.context_pools, self.context_linears, self.blocks):
            context = context_linear(pool(x))  # [B, 3, h], the same for every point
            x = block(x + context.unsqueeze(1))
        # No norm before the last linear: the un-normalised residual stream carries the object's size.
        z: torch.Tensor = self.to_latent(self.final_pool(x))  # [B, 3, latent - cues]
        return z
