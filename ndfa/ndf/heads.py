"""The NDF's heads on z besides the decoder: the learned shape code (`GramCode`), the gated center
head (`GatedCenterHead`; several averaged: `CenterHeadEnsemble`) and the category head on the code
(`CategoryHead`). All are equivariant in z: the code and the category are invariant, the center
offset rotates with z."""

from __future__ import annotations

import torch
from torch import nn

from ndfa.ndf.config import NDFConfig
from ndfa.ndf.vn import VNLinear, vn_invariant


class GramCode(nn.Module):
    """Shape code from all rotation invariants of z: `[B, 3, k] -> [B, code_dim]`.

    z is projected to m vectors; their m x m Gram matrix (upper triangle) fixes them up to a
    rotation, so it keeps everything about shape that a rotation-invariant code can keep.
    """

    upper: torch.Tensor  # (2, m(m+1)/2) row and column indices of the Gram matrix's upper triangle

    def __init__(self, config: NDFConfig) -> None:
        super().__init__()
        m = config.gram_channels
        self.project = VNLinear(config.latent - int(config.view_cue), m)  # z without the view ray
        self.register_buffer("upper", torch.triu_indices(m, m), persistent=False)
        # Standardising the invariants with dataset statistics (running mean and variance) keeps
        # the codes apart from the first step: at initialisation z is tiny, the raw Gram entries
        # are ~0, every code equals the MLP's bias, and the cosine-based shape loss has no
        # gradient at identical codes (measured: codes stayed collapsed for 250+ steps at alpha
        # 0.01 without it). Unlike a per-sample norm it keeps the mug's size in the code.
        self.standardise = nn.BatchNorm1d(m * (m + 1) // 2, eps=config.gram_eps)
        self.mlp = nn.Sequential(
            nn.Linear(m * (m + 1) // 2, 2 * config.code_dim), nn.ReLU(), nn.Linear(2 * config.code_dim, config.code_dim)
        )
        # The codes leave the head standardised over the data (no affine part), so they cannot
        # all coincide: any cosine-based loss has zero gradient at identical codes, and in
        # training runs without this the codes collapsed to one vector within 250 steps.
        self.whiten = nn.BatchNorm1d(config.code_dim, affine=False)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        projected = self.project(z)
        gram = vn_invariant(projected, projected)  # [B, m, m]
        code: torch.Tensor = self.whiten(self.mlp(self.standardise(gram[:, self.upper[0], self.upper[1]])))
        return code


class GatedCenterHead(nn.Module):
    """Center offset from z, `[B, 3, k] -> [B, 3, 1]`: a VN-linear channel plus sum_j w_j(z) z_j, the
    weights w an MLP of z's invariants (its dot products with a learned 3-vector frame). The
    weights start at zero, so a fresh head is the linear one."""

    def __init__(self, config: NDFConfig, frame: int = 4, width: int = 128) -> None:
        super().__init__()
        k = config.latent
        self.linear = VNLinear(k, 1)
        self.frame = VNLinear(k, frame)
        self.weights = nn.Sequential(nn.Linear(k * frame, width), nn.ReLU(), nn.Linear(width, k))
        last = self.weights[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        invariants = vn_invariant(z, self.frame(z)).flatten(1)  # [B, k * frame]
        # [B, 3, 1], as VNLinear(k, 1)
        offset: torch.Tensor = self.linear(z) + z @ self.weights(invariants).unsqueeze(-1)
        return offset


class CenterHeadEnsemble(nn.Module):
    """`NDFConfig.center_refits` gated center heads, `[B, 3, k] -> [B, 3, 1]`: their mean offset."""

    def __init__(self, config: NDFConfig) -> None:
        super().__init__()
        self.members = nn.ModuleList(GatedCenterHead(config) for _ in range(config.center_refits))

    def each(self, z: torch.Tensor) -> torch.Tensor:
        """Every member's offset, `[K, B, 3, 1]` (training fits each on its own loss)."""
        return torch.stack([member(z) for member in self.members])

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.each(z).mean(0)


class CategoryHead(nn.Module):
    """Category logits from the shape code, `[B, code_dim] -> [B, len(categories)]`: a small MLP
    on the (rotation-invariant) code, so the category is as invariant as the code. Training's
    cross-entropy also shapes the code, so that objects of one category share a region of it."""

    def __init__(self, config: NDFConfig, width: int = 64) -> None:
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(config.code_dim_out, width), nn.ReLU(), nn.Linear(width, len(config.categories)))

    def forward(self, code: torch.Tensor) -> torch.Tensor:
        logits: torch.Tensor = self.mlp(code)
        return logits
