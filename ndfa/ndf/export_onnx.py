"""The NDF's detection-time computation as two ONNX graphs, for ONNX Runtime (`ndfa.ndf.runtime`).

    encode graph      centred points [B, N, 3], up [B, 3], view ray [B, 3]
                          -> z [B, k, 3], shape code [B, D], center offset [B, 3] (metres),
                             and for a model with categories (NDF v3) their probabilities
                             [B, len(NDFConfig.categories)] (softmax of `category_logits`)
    occupancy graph   z [B, k, 3], centred queries [B, Q, 3], centred points [B, N, 3]
                          -> occupancy [B, Q] (sigmoid of the decoder's logits)

The graphs compute what `NDFModel.encode`, `shape_code`, `center_offset` and `occupancy_logits`
compute, from the same parameters (the modules below hold the trained model's own layers), but
the encoder is written for inference rather than training:

- Vector features are `[B, 3, N, C]` (the vector axis before the points) instead of the training
  layout `[B, N, 3, C]`. Every VN dot product is a sum over that axis; there it adds three
  contiguous slabs, where the training layout reduces an axis of 3 between N and C, which ONNX
  Runtime ran as its slowest op (15% of the encoder).
- The local edge layer uses what the three edge vectors are: e = [p, n, p x n] with n = p_j - p_i.
  Their Gram matrix has four distinct entries, |p|^2, p.n, |n|^2 and |p x n|^2 = |p|^2 |n|^2 -
  (p.n)^2 (p x n is orthogonal to both), and sums of coef * (p x n) over the neighbours are
  p x (sum of coef * n). `VNEdgeConv` computes the full 3 x 3 Gram matrix per edge with batched
  3 x 3 matmuls (the encoder's slowest op in torch and in ONNX Runtime). Per edge and channel only
  k's coefficient is computed (two matmuls of the invariants, a ReLU, a division: the edge tensors
  `[B, N, K, C]` are the layer's memory traffic); the sums over the neighbours of coef and coef * n
  are one small matmul per point, and everything else is per point (docs/speed.md, 2026-12-03).
- The decoder's residual MLP runs on `[B * Q, width]`, where ONNX Runtime fuses each linear
  layer with its bias and ReLU.

The results agree with torch to float32 rounding (`tests/test_ndf_runtime.py` states the
tolerances). Export runs in memory: nothing is written here, and the graphs always belong to the
weights loaded.
"""

from __future__ import annotations

import io
import warnings
from typing import Any

import torch
from torch import nn

from ndfa.ndf.decoder import DECODER_GAIN, ResnetBlockFC, object_frame
from ndfa.ndf.model import NDFModel
from ndfa.ndf.vn import EPS, VNLeakyReLU, VNResnetBlock

OPSET = 17
ENCODE_INPUTS = ("points", "up", "view_ray")
ENCODE_OUTPUTS = ("z", "shape_code", "center_offset")
CATEGORY_OUTPUT = "category_probabilities"  # an encode graph's fourth output, with a category head
OCCUPANCY_INPUTS = ("z", "queries", "points")
OCCUPANCY_OUTPUTS = ("occupancy",)


def _vn_relu(act: VNLeakyReLU, q: torch.Tensor) -> torch.Tensor:
    """`VNLeakyReLU` with the vector axis at 1 (`[B, 3, ..., C]`); the slope's factor (negative)
    goes inside a ReLU instead of a clamp and a product: (slope - 1) min(q.k, 0) = relu((slope - 1) q.k)."""
    k = act.direction(q)
    dot = (q * k).sum(1, keepdim=True)
    k_norm_sq = (k * k).sum(1, keepdim=True)
    out: torch.Tensor = q + torch.relu(dot * (act.negative_slope - 1.0)) / (k_norm_sq + EPS) * k
    return out


def _vn_block(block: VNResnetBlock, x: torch.Tensor) -> torch.Tensor:
    """`VNResnetBlock` on `[B, 3, N, C]`; its norm is per point (over the vector axis and C)."""
    inverse_rms = torch.rsqrt(x.pow(2).sum((1, 3), keepdim=True) / x.shape[-1] + EPS)  # 3 * mean = sum / C
    h = block.linear_0(_vn_relu(block.act_0, x * (block.norm.gain * inverse_rms)))
    out: torch.Tensor = block.shortcut(x) + block.linear_1(_vn_relu(block.act_1, h))
    return out


def _cross_along_2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a x b for vectors along axis 2 (`[B, N, 3, ...]`, broadcasting), from the components rolled by one and by two."""
    roll_1, roll_2 = [1, 2, 0], [2, 0, 1]
    out: torch.Tensor = a[:, :, roll_1] * b[:, :, roll_2] - a[:, :, roll_2] * b[:, :, roll_1]
    return out


class InferenceEncode(nn.Module):
    """`NDFModel.encode` + `shape_code` + `center_offset` (+ the category probabilities), for the
    export (see the module doc)."""

    def __init__(self, model: NDFModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, points: torch.Tensor, up: torch.Tensor, view_ray: torch.Tensor) -> tuple[torch.Tensor, ...]:
        model, encoder = self.model, self.model.encoder
        if model.config.pooling != "mean":
            raise NotImplementedError("the ONNX export covers mean pooling (the shipped weights')")
        cues = model.cue_vectors(up, view_ray)  # [B, 3, cues]
        x = self._local(points * model.config.input_scale)  # [B, 3, N, h]
        if encoder.up_in is not None:
            assert cues is not None  # up_cue implies the cues
            x = x + encoder.up_in(cues[..., :1]).unsqueeze(2)
        for context_linear, block in zip(encoder.context_linears, encoder.blocks):
            assert isinstance(block, VNResnetBlock)
            x = _vn_block(block, x + context_linear(x.mean(2)).unsqueeze(2))
        z_channels = encoder.to_latent(x.mean(2))  # [B, 3, latent - cues]
        if cues is not None:
            z_channels = torch.cat([z_channels, cues], dim=-1)
        z = z_channels.transpose(-1, -2)
        code = model.shape_code(z)
        if model.category_head is None:
            return z, code, model.center_offset(z)
        return z, code, model.center_offset(z), torch.softmax(model.category_logits(code), dim=-1)

    def _local(self, points: torch.Tensor) -> torch.Tensor:
        """`VNEdgeConv(knn_edge_features(points))` as `[B, 3, N, h]`, from the edges' four invariants
        (module doc): per edge only the coefficient of k; its sums over the neighbours come from one
        small matmul per point, and the cross products from those sums."""
        conv = self.model.encoder.local
        batch, count = points.shape[0], points.shape[1]
        k = min(self.model.encoder.knn, count)
        norm_sq = (points * points).sum(-1)  # [B, N]; as `knn_edge_features`: the same neighbours
        ranking = torch.baddbmm(norm_sq.unsqueeze(-2), points, points.transpose(-1, -2), alpha=-2.0)
        neighbour_index = ranking.topk(k, largest=False, sorted=False).indices  # [B, N, K], in any order
        # The neighbours' coordinates component by component, [3, B, N, K]: the per-edge arithmetic
        # then runs on contiguous [B, N, K] slabs (ONNX Runtime broadcasts a trailing 3 slowly).
        coordinates = points.reshape(-1, 3).transpose(0, 1)  # [3, B * N]
        p = points.permute(2, 0, 1).unsqueeze(-1)  # [3, B, N, 1]
        offsets = coordinates[:, neighbour_index + (torch.arange(batch) * count)[:, None, None]] - p  # n = p_j - p_i
        pp = norm_sq.unsqueeze(-1)  # [B, N, 1]
        pn = (offsets * p).sum(0)  # [B, N, K]
        nn_ = (offsets * offsets).sum(0)
        xx = pp * nn_ - pn * pn  # |p x n|^2
        ones = torch.ones_like(pn)
        invariants = torch.stack([pp.expand_as(pn), pn, nn_, xx, ones], dim=-1)  # [B, N, K, 5]
        w = conv.linear.linear.weight  # [h, 3]: q_c = sum_a w[c, a] e_a, e = (p, n, p x n)
        v = conv.act.direction.weight @ w  # [h, 3]: k_c = sum_a v[c, a] e_a
        # q.k = w0 v0 |p|^2 + (w0 v1 + w1 v0) p.n + w1 v1 |n|^2 + w2 v2 |p x n|^2, and |k|^2 alike; the
        # last row multiplies the ones: |k|^2 + EPS in the same matmul
        dot_weights = torch.stack([w[:, 0] * v[:, 0], w[:, 0] * v[:, 1] + w[:, 1] * v[:, 0], w[:, 1] * v[:, 1],
                                   w[:, 2] * v[:, 2], torch.zeros_like(w[:, 0])])  # [5, h]
        norm_weights = torch.stack([v[:, 0] * v[:, 0], 2.0 * v[:, 0] * v[:, 1], v[:, 1] * v[:, 1], v[:, 2] * v[:, 2],
                                    torch.full_like(w[:, 0], EPS)])
        # `k_coefficient`, its negative factor inside the ReLU (as `_vn_relu`): [B, N, K, h]
        coef = torch.relu(invariants @ (dot_weights * (conv.act.negative_slope - 1.0))) / (invariants @ norm_weights)
        # Per point, the means over the neighbours of coef_c and of coef_c n: [1, n] as rows times coef
        rows = torch.cat([ones.unsqueeze(0), offsets]).permute(1, 2, 0, 3)  # [B, N, 4, K]
        moments = (rows @ coef) / k  # [B, N, 4, h]
        coef_mean, coef_n = moments[:, :, :1], moments[:, :, 1:]  # [B, N, 1, h], [B, N, 3, h]
        p_vector = points.unsqueeze(-1)  # [B, N, 3, 1]
        mean_n = offsets.mean(-1).permute(1, 2, 0).unsqueeze(-1)  # [B, N, 3, 1]
        # out_c = W mean(e) + V mean(coef_c e): p, mean n and p x mean n mix by W's columns (a matmul),
        # and mean(coef_c p x n) = p x mean(coef_c n)
        basis = torch.cat([p_vector, mean_n, _cross_along_2(p_vector, mean_n)], dim=-1)  # [B, N, 3, 3]
        out = (basis @ w.T + p_vector * (coef_mean * v[:, 0]) + coef_n * v[:, 1]
               + _cross_along_2(p_vector, coef_n) * v[:, 2])  # [B, N, 3, h]
        return out.transpose(1, 2)


class InferenceOccupancy(nn.Module):
    """`sigmoid(NDFModel.occupancy_logits)`, its residual MLP on `[B * Q, width]`."""

    def __init__(self, model: NDFModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, z: torch.Tensor, queries: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        model, decoder = self.model, self.model.decoder
        scale = model.config.input_scale
        z_channels, queries, points = z.transpose(-1, -2), queries * scale, points * scale
        center = model.frame_origin(z) * scale if decoder.use_frame else None
        if center is not None:
            queries = queries - center.unsqueeze(1)
        query_features = [(queries * queries).sum(-1, keepdim=True), queries @ z_channels]
        frame = decoder.frame(z_channels)
        if decoder.use_frame:
            frame = object_frame(frame)
            local = queries @ frame
            query_features += [DECODER_GAIN * local, DECODER_GAIN * local * local]
        shape_features = (z_channels.transpose(-1, -2) @ frame).flatten(1)
        h = decoder.query_in(torch.cat(query_features, dim=-1)) + decoder.shape_in(shape_features).unsqueeze(1)
        if decoder.local_in is not None:
            assert center is not None  # local points need the frame decoder (NDFConfig)
            h = h + decoder.local_in(decoder._nearest_offsets(queries, points - center.unsqueeze(1), frame))
        batch, count, width = h.shape
        flat = h.reshape(-1, width)
        for block in decoder.blocks:
            assert isinstance(block, ResnetBlockFC)
            flat = flat + block.linear_1(torch.relu(block.linear_0(torch.relu(flat))))
        logits = decoder.out(torch.relu(flat)).reshape(batch, count)
        return torch.sigmoid(logits)


def export_onnx(model: NDFModel, n_points: int) -> tuple[bytes, bytes]:
    """The (encode, occupancy) graphs of `model` as serialised ONNX models, batch and query
    counts dynamic."""
    model = model.eval()
    points = torch.randn(2, n_points, 3) * 0.03
    up, view_ray = torch.tensor([[0.0, -1.0, 0.0]] * 2), torch.tensor([[0.0, 0.0, 1.0]] * 2)
    with torch.no_grad():
        z = model.encode(points, up, view_ray)
    queries = torch.randn(2, 50, 3) * 0.05
    encode_outputs = ENCODE_OUTPUTS + ((CATEGORY_OUTPUT,) if model.category_head is not None else ())
    encode = _export(InferenceEncode(model), (points, up, view_ray), ENCODE_INPUTS, encode_outputs,
                     {name: {0: "batch"} for name in ENCODE_INPUTS + encode_outputs})
    axes = {name: {0: "batch"} for name in ("z", "points")} | {name: {0: "batch", 1: "queries"} for name in ("queries", "occupancy")}
    occupancy = _export(InferenceOccupancy(model), (z, queries, points), OCCUPANCY_INPUTS, OCCUPANCY_OUTPUTS, axes)
    return encode, occupancy


def _export(module: nn.Module, args: tuple[torch.Tensor, ...], inputs: tuple[str, ...], outputs: tuple[str, ...],
            dynamic_axes: dict[str, dict[int, str]]) -> bytes:
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        # The TorchScript-based exporter: it traces this fixed graph in one pass (the torch.export
        # one needs onnxscript) and warns that it is deprecated and that traced shapes are constants.
        warnings.simplefilter("ignore")
        target: Any = buffer  # a file object is accepted, though the annotation names paths only
        torch.onnx.export(module.eval(), args, target, input_names=list(inputs), output_names=list(outputs),
                          dynamic_axes=dynamic_axes, opset_version=OPSET, dynamo=False)
    return buffer.getvalue()
