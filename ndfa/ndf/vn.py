"""Vector-neuron (VN) layers: building blocks whose outputs rotate exactly as their inputs do.

Deng et al., "Vector Neurons: A General Framework for SO(3)-Equivariant Networks" (ICCV 2021).
A VN feature is a list of C 3-vectors instead of C scalars. If every layer maps features rotated
by R to outputs rotated by R (f(R x) = R f(x), "equivariant"), the whole network is, and an
encoder built from them gives a latent code z that turns with the object.

Layout (channels-last): per-point features are `[B, N, 3, C]`, pooled (per-object) features
`[B, 3, C]`; every layer here accepts any leading dims `[..., 3, C]`. A rotation R acts on the
`3` axis (x -> R x per channel); layers mix only the `C` axis or use rotation-invariant
quantities (norms, dot products), which is why they commute with R. The original VN code (and the
issue text) uses `[B, C, 3, N]`; we deviate on purpose: with C last, `nn.Linear` works on a
contiguous axis and an NDF-sized training step measured 3x faster on CPU (7 s vs 23 s).
"""

from __future__ import annotations

import torch
from torch import nn

EPS = 1e-6  # keeps divisions by vector norms finite; norms are invariant, so equivariance holds


class VNLinear(nn.Module):
    """Linear mixing of vector channels, `[..., 3, in_c] -> [..., 3, out_c]`.

    Bias-free on purpose: adding a constant vector would not rotate with the input.
    """

    def __init__(self, in_c: int, out_c: int) -> None:
        super().__init__()
        self.linear = nn.Linear(in_c, out_c, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mixed: torch.Tensor = self.linear(x)
        return mixed


class VNLeakyReLU(nn.Module):
    """The VN nonlinearity, `[..., 3, c] -> [..., 3, c]`.

    Each channel q gets a direction k (a learned linear map of the same features, so k rotates
    with q). Where q points along k (q.k >= 0) it passes; otherwise its component along k is
    removed, the vector analogue of ReLU's "clip the negative half". The leaky version keeps a
    fraction `negative_slope` of the removed component:
        out = q - (1 - slope) * [q.k < 0] * (q.k / |k|^2) k
    """

    def __init__(self, c: int, negative_slope: float = 0.2) -> None:
        super().__init__()
        self.direction = nn.Linear(c, c, bias=False)
        self.negative_slope = negative_slope

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        k = self.direction(q)
        dot = (q * k).sum(-2, keepdim=True)  # [..., 1, c], invariant
        k_norm_sq = (k * k).sum(-2, keepdim=True)
        return torch.addcmul(q, self.k_coefficient(dot, k_norm_sq), k)

    def k_coefficient(self, dot: torch.Tensor, k_norm_sq: torch.Tensor) -> torch.Tensor:
        """The coefficient of k in the output: -(1 - slope) q.k / |k|^2 where q.k < 0, else 0."""
        return dot.clamp(max=0.0) / (k_norm_sq + EPS) * (self.negative_slope - 1.0)


class VNLayerNorm(nn.Module):
    """Scale each point's features so that its channel norms have unit RMS, `[..., 3, c]`.

    Only rescales vectors by an invariant number (plus a learned per-channel gain), so it is
    equivariant. Chosen over VN batch-norm (batch statistics of the vector norms) because it has
    no batch statistics and no running averages: a view's features do not depend on what else is
    in the batch, train and eval modes compute the same thing, and it is as stable at batch 1 as at
    batch 32. The shape codes of single views are compared at inference, so this matters.
    """

    def __init__(self, c: int) -> None:
        super().__init__()
        self.gain = nn.Parameter(torch.ones(c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # mean over channels of |x_c|^2 = 3 * mean over all 3c entries; one pass, no [..., 1, c] temporary
        inverse_rms = torch.rsqrt(3.0 * x.pow(2).mean((-2, -1), keepdim=True) + EPS)  # [..., 1, 1]
        return x * (self.gain * inverse_rms)


class VNResnetBlock(nn.Module):
    """Pre-norm residual block, `[..., 3, in_c] -> [..., 3, out_c]`:
    out = shortcut(x) + Linear(ReLU(Linear(ReLU(Norm(x))))), with the VN ReLU and linear layers.

    One norm per block: the residual stream grows from block to block and needs it; the second
    nonlinearity sees a linear map of normalised features, already well scaled. The last linear
    starts at zero so that a new block is the identity (as in Occupancy Networks' ResnetBlockFC),
    and deep stacks train from the first step.
    """

    def __init__(self, in_c: int, out_c: int, hidden_c: int | None = None) -> None:
        super().__init__()
        hidden_c = hidden_c or out_c
        self.norm = VNLayerNorm(in_c)
        self.act_0, self.linear_0 = VNLeakyReLU(in_c), VNLinear(in_c, hidden_c)
        self.act_1, self.linear_1 = VNLeakyReLU(hidden_c), VNLinear(hidden_c, out_c)
        nn.init.zeros_(self.linear_1.linear.weight)
        self.shortcut = VNLinear(in_c, out_c) if in_c != out_c else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.linear_0(self.act_0(self.norm(x)))
        out: torch.Tensor = self.shortcut(x) + self.linear_1(self.act_1(h))
        return out


class VNEdgeConv(nn.Module):
    """VNLeakyReLU(VNLinear(e)) averaged over neighbours: `[..., K, 3, in_c] -> [..., 3, out_c]`.

    The encoder's local layer runs on every (point, neighbour) edge, and materialising the
    per-edge output `[B, N, K, 3, out_c]` dominated a training step. For few input channels
    (3 here) it need not be: per edge, q = W e and k = U W e are combinations of the in_c edge
    vectors, so q.k and |k|^2 follow from the in_c x in_c Gram matrix G = e^T e, and the mean of
    q + coef k over the K edges is W mean(e) + U W (mean of coef e). Same result as
    `self.act(self.linear(e)).mean(-3)` (a test checks it); a training step of this layer ran 3.5x
    faster (0.73 s -> 0.21 s, batch 32 x 400 points x 16 neighbours).
    """

    def __init__(self, in_c: int, out_c: int, negative_slope: float = 0.2) -> None:
        super().__init__()
        self.linear = VNLinear(in_c, out_c)
        self.act = VNLeakyReLU(out_c, negative_slope)

    def forward(self, e: torch.Tensor) -> torch.Tensor:
        w = self.linear.linear.weight  # [out_c, in_c]: q_c = sum_a w[c, a] e_a
        v = self.act.direction.weight @ w  # [out_c, in_c]: k_c = sum_a v[c, a] e_a
        gram = (e.transpose(-1, -2) @ e).flatten(-2)  # [..., K, in_c^2]: e_a . e_b, invariant
        # q_c . k_c = sum_ab w[c, a] v[c, b] G_ab and |k_c|^2 = sum_ab v[c, a] v[c, b] G_ab, in one matmul
        pair_weights = torch.cat([w[:, :, None] * v[:, None, :], v[:, :, None] * v[:, None, :]]).flatten(1)
        dot, k_norm_sq = (gram @ pair_weights.T).chunk(2, dim=-1)  # [..., K, out_c] each
        coef = self.act.k_coefficient(dot, k_norm_sq)  # [..., K, out_c]
        # sum over edges of coef_c e: [..., out_c, K] @ [..., K, 3 * in_c] -> [..., out_c, 3, in_c]
        coef_e = torch.unflatten(coef.transpose(-1, -2) @ e.flatten(-2), -1, e.shape[-2:])
        mean_coef_k = torch.einsum("...cda,ca->...dc", coef_e, v / e.shape[-3])  # [..., 3, out_c]
        out: torch.Tensor = self.linear(e.mean(-3)) + mean_coef_k
        return out


def vn_mean_pool(x: torch.Tensor) -> torch.Tensor:
    """Mean over points, `[..., N, 3, C] -> [..., 3, C]`. Equivariant: a mean of rotated vectors."""
    return x.mean(-3)


def vn_max_pool(x: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """VN max-pool over points, `[..., N, 3, C] -> [..., 3, C]`.

    Per channel, keeps the point whose vector reaches furthest along its direction (the largest
    x.k, an invariant), so the chosen point does not change under rotation. `direction` has the
    shape of `x`, usually `VNLinear(C, C)(x)`.
    """
    score = (x * direction).sum(-2)  # [..., N, C]
    best = score.argmax(-2, keepdim=True)  # [..., 1, C]
    index = best.unsqueeze(-2).expand(*x.shape[:-3], 1, 3, x.shape[-1])  # [..., 1, 3, C]
    return x.gather(-3, index).squeeze(-3)


def vn_invariant(x: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """Rotation-invariant features: all dot products of x's channels with frame's, `[..., C, F]`.

    x: `[..., 3, C]`, frame: `[..., 3, F]`, both equivariant (usually frame = VNLinear(C, F)(x)).
    (R x)^T (R frame) = x^T frame, so the result does not change when both rotate. With frame = x
    this is the Gram matrix of x, which determines x up to a rotation (or reflection).
    """
    return x.transpose(-1, -2) @ frame
