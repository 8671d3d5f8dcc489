"""The NDF's detection-time computation as two ONNX graphs, for ONNX Runtime (`ndfa.ndf.runtime`).

    encode graph      centred points [B, N, 3], up [B, 3], view ray [B, 3]
                          -> z [B, k, 3], shape code [B, D], center offset [B, 3] (metres)
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
  3 x 3 matmuls (the encoder's slowest op in torch and in ONNX Runtime).
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
OCCUPANCY_INPUTS = ("z", "queries", "points")
OCCUPANCY_OUTPUTS = ("occupancy",)


def _vn_relu(act: VNLeakyReLU, q: torch.Tensor) -> torch.Tensor:
    """`VNLeakyReLU` with the vector axis at 1 (`[B, 3, ..., C]`)."""
    k = act.direction(q)
    dot = (q * k).sum(1, keepdim=True)
    k_norm_sq = (k * k).sum(1, keepdim=True)
    out: torch.Tensor = q + act.k_coefficient(dot, k_norm_sq) * k
    return out


def _vn_block(block: VNResnetBlock, x: torch.Tensor) -> torch.Tensor:
    """`VNResnetBlock` on `[B, 3, N, C]`; its norm is per point (over the vector axis and C)."""
    inverse_rms = torch.rsqrt(3.0 * x.pow(2).mean((1, 3), keepdim=True) + EPS)
    h = block.linear_0(_vn_relu(block.act_0, x * (block.norm.gain * inverse_rms)))
    out: torch.Tensor = block.shortcut(x) + block.linear_1(_vn_relu(block.act_1, h))
    return out


def _cross(a: tuple[torch.Tensor, ...], b: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
    """a x b for vectors given as their three components (broadcasting)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


class InferenceEncode(nn.Module):
    """`NDFModel.encode` + `shape_code` + `center_offset`, for the export (see the module doc)."""

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
        return z, model.shape_code(z), model.center_offset(z)

    def _local(self, points: torch.Tensor) -> torch.Tensor:
        """`VNEdgeConv(knn_edge_features(points))` as `[B, 3, N, h]`, from the edges' four invariants."""
        conv = self.model.encoder.local
        k = min(self.model.encoder.knn, points.shape[1])
        norm_sq = (points * points).sum(-1).unsqueeze(-2)  # as `knn_edge_features`: the same neighbours
        ranking = torch.baddbmm(norm_sq, points, points.transpose(-1, -2), alpha=-2.0)
        neighbour_index = ranking.topk(k, largest=False, sorted=False).indices  # [B, N, K]
        batch_index = torch.arange(points.shape[0])[:, None, None]
        offsets = points[batch_index, neighbour_index] - points.unsqueeze(2)  # n = p_j - p_i, [B, N, K, 3]
        p = points.unsqueeze(2)  # [B, N, 1, 3]
        pp = (p * p).sum(-1)  # [B, N, 1]
        pn = (offsets * p).sum(-1)  # [B, N, K]
        nn_ = (offsets * offsets).sum(-1)
        xx = pp * nn_ - pn * pn  # |p x n|^2
        invariants = torch.stack([pp.expand_as(pn), pn, nn_, xx], dim=-1)  # [B, N, K, 4]
        w = conv.linear.linear.weight  # [h, 3]: q_c = sum_a w[c, a] e_a, e = (p, n, p x n)
        v = conv.act.direction.weight @ w  # [h, 3]: k_c = sum_a v[c, a] e_a
        # q.k = w0 v0 |p|^2 + (w0 v1 + w1 v0) p.n + w1 v1 |n|^2 + w2 v2 |p x n|^2, and |k|^2 alike
        dot_weights = torch.stack([w[:, 0] * v[:, 0], w[:, 0] * v[:, 1] + w[:, 1] * v[:, 0], w[:, 1] * v[:, 1],
                                   w[:, 2] * v[:, 2]])  # [4, h]
        norm_weights = torch.stack([v[:, 0] * v[:, 0], 2.0 * v[:, 0] * v[:, 1], v[:, 1] * v[:, 1], v[:, 2] * v[:, 2]])
        dot, k_norm_sq = invariants @ dot_weights, invariants @ norm_weights  # [B, N, K, h] each
        coef = conv.act.k_coefficient(dot, k_norm_sq)
        count = offsets.shape[2]
        coef_sum = coef.sum(2)  # [B, N, h]
        coef_n = (coef.transpose(-1, -2) @ offsets) / count  # [B, N, h, 3]: mean of coef_c * n
        p_c = tuple(points[..., d].unsqueeze(-1) for d in range(3))  # [B, N, 1] each
        mean_n = offsets.mean(2)
        mean_n_c = tuple(mean_n[..., d].unsqueeze(-1) for d in range(3))
        coef_n_c = tuple(coef_n[..., d] for d in range(3))  # [B, N, h] each
        p_x_mean_n, p_x_coef_n = _cross(p_c, mean_n_c), _cross(p_c, coef_n_c)
        # out_c = W mean(e) + V mean(coef_c e), per component
        out = [w[:, 0] * p_c[d] + w[:, 1] * mean_n_c[d] + w[:, 2] * p_x_mean_n[d]
               + v[:, 0] * p_c[d] * coef_sum / count + v[:, 1] * coef_n_c[d] + v[:, 2] * p_x_coef_n[d]
               for d in range(3)]
        return torch.stack(out, dim=1)


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
    encode = _export(InferenceEncode(model), (points, up, view_ray), ENCODE_INPUTS, ENCODE_OUTPUTS,
                     {name: {0: "batch"} for name in ENCODE_INPUTS + ENCODE_OUTPUTS})
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
