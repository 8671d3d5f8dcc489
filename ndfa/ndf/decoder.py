"""The NDF's occupancy decoder Phi(x, z): occupancy logits of query points from rotation-invariant
features of the queries and z (`OccupancyDecoder`), and the object frame it may build from z."""

from __future__ import annotations

import torch
from torch import nn

from ndfa.core.errors import ModelError
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.vn import EPS, VNLinear, vn_invariant

# The frame decoder reads coordinates (and their squares, and offsets to nearby points) 10x the
# encoder's scale, i.e. in centimetres: a 3-8 mm wall then spans 0.3-0.8 input units, a step that
# freshly initialised ReLU layers resolve. Without this (and without local points) a 750-step run
# still predicted every validation query empty; with both, it predicted occupied ones by step 250.
DECODER_GAIN = 10.0


class ResnetBlockFC(nn.Module):
    """Plain residual MLP block, out = x + Linear(ReLU(Linear(ReLU(x)))), the last layer zero-init."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.linear_0 = nn.Linear(width, width)
        self.linear_1 = nn.Linear(width, width)
        nn.init.zeros_(self.linear_1.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = x + self.linear_1(torch.relu(self.linear_0(torch.relu(x))))
        return out


def object_frame(vectors: torch.Tensor) -> torch.Tensor:
    """An orthonormal, right-handed frame `[..., 3, 3]` (columns) from two vectors `[..., 3, 2]`.

    Gram-Schmidt, then a cross product: every step commutes with a rotation, so the frame rotates
    with its input, and coordinates in it (frame^T x) are rotation-invariant.
    """
    first = vectors[..., 0]
    first = first / (first.norm(dim=-1, keepdim=True) + EPS)
    second = vectors[..., 1] - (vectors[..., 1] * first).sum(-1, keepdim=True) * first
    second = second / (second.norm(dim=-1, keepdim=True) + EPS)
    return torch.stack([first, second, torch.linalg.cross(first, second, dim=-1)], dim=-1)


class OccupancyDecoder(nn.Module):
    """Phi(x, z): occupancy logits of queries from rotation-invariant features only.

    Per query: |x|^2 and x . z_j for all j (invariant when x and z rotate together), and with the
    "frame" decoder x's coordinates u = F^T x in an orthonormal frame F made from z, with their
    squares, x then being taken from the predicted center (the center head's). Per object: z's coordinates in a learned frame (F itself for "frame"). The per-object
    part enters the first layer once per object and is broadcast over the queries, which saves a
    matmul per query.
    """

    def __init__(self, config: NDFConfig) -> None:
        super().__init__()
        k, width = config.latent, config.decoder_width
        self.use_frame = config.decoder == "frame"
        self.local_points = config.local_points
        self.frame = VNLinear(k, 2 if self.use_frame else 3)
        self.query_in = nn.Linear(1 + k + (6 if self.use_frame else 0), width)
        self.local_in = nn.Linear(4 * self.local_points, width, bias=False) if self.local_points else None
        self.shape_in = nn.Linear(3 * k, width, bias=False)
        self.blocks = nn.Sequential(*(ResnetBlockFC(width) for _ in range(config.decoder_blocks)))
        self.out = nn.Linear(width, 1)

    def forward(self, z: torch.Tensor, queries: torch.Tensor, center: torch.Tensor | None = None,
                points: torch.Tensor | None = None) -> torch.Tensor:
        """z: `[B, 3, k]`, queries: `[B, Q, 3]`, both scaled; for the "frame" decoder the predicted
        center `[B, 3]` (scaled), which becomes the frame's origin, and with `local_points` the
        input points `[B, N, 3]` (scaled). Returns logits `[B, Q]`."""
        if self.use_frame:
            # Relative to the object's center rather than the visible points' centroid: then the
            # radius of a query from the mug's axis is a sum of squared frame coordinates, which
            # the MLP gets as inputs, instead of a product of query and shape it would have to learn.
            assert center is not None  # NDFModel.occupancy_logits passes it to the "frame" decoder
            queries = queries - center.unsqueeze(1)
        query_features = [(queries * queries).sum(-1, keepdim=True), queries @ z]
        frame = self.frame(z)
        if self.use_frame:
            frame = object_frame(frame)  # [B, 3, 3]
            local = queries @ frame  # [B, Q, 3]: the queries in the object's own frame
            query_features += [DECODER_GAIN * local, DECODER_GAIN * local * local]
        shape_features = vn_invariant(z, frame).flatten(1)  # [B, 3k]
        h = self.query_in(torch.cat(query_features, dim=-1)) + self.shape_in(shape_features).unsqueeze(1)
        if self.local_in is not None:
            if points is None:
                raise ModelError("this model's decoder needs the input points (local_points > 0)")
            assert center is not None  # local points are offsets from the predicted center
            h = h + self.local_in(self._nearest_offsets(queries, points - center.unsqueeze(1), frame))
        logits: torch.Tensor = self.out(torch.relu(self.blocks(h))).squeeze(-1)
        return logits

    def _nearest_offsets(self, queries: torch.Tensor, points: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
        """Per query, the offsets to its `local_points` nearest points in the object frame and their
        lengths, nearest first, scaled by DECODER_GAIN: `[B, Q, 4 * local_points]`, invariant."""
        k = min(self.local_points, points.shape[1])
        with torch.no_grad():  # which points are nearest needs no gradient
            norm_sq = (points * points).sum(-1).unsqueeze(-2)  # [B, 1, N]; |q|^2 does not change the ranking
            ranking = torch.baddbmm(norm_sq, queries, points.transpose(-1, -2), alpha=-2.0)  # [B, Q, N]
            nearest = ranking.topk(k, largest=False).indices  # [B, Q, k]
        batch_index = torch.arange(points.shape[0], device=points.device)[:, None, None]
        offsets = (points[batch_index, nearest] - queries.unsqueeze(2)) @ frame.unsqueeze(1)  # [B, Q, k, 3]
        features = torch.cat([offsets, offsets.norm(dim=-1, keepdim=True)], dim=-1)
        if k < self.local_points:  # fewer input points than neighbours asked for: repeat the last
            features = torch.cat([features, features[:, :, -1:].expand(-1, -1, self.local_points - k, -1)], dim=2)
        return DECODER_GAIN * features.flatten(2)
