"""The Neural Descriptor Field model (Simeonov et al., ICRA 2022) as used by Fu et al. (IROS 2022).

    encoder      f(P) = z              partial point cloud [B, N, 3] -> k vectors z [B, k, 3]
    decoder      Phi(x, z)             occupancy logit of query points x [B, Q, 3]
    shape code   s(z)                  rotation-invariant descriptor of the full shape [B, D]
    center head  t(z)                  offset of the full shape's center from the input's centroid

Frames: the caller zero-centres a view (subtracts its centroid, which holds the translation) and
gives the same centring to the queries; the model then works in that object-centred frame, in
metres. Inside, coordinates are multiplied by the fixed `input_scale` so a mug is about unit size.
Everything is built from vector-neuron layers (`ndfa.ndf.vn`), so rotating the input by R rotates
z and the center offset by R and leaves the shape code and the occupancy of jointly rotated
queries unchanged; the tests check this to 1e-4.

Optional direction cues (`NDFConfig.up_cue`, `view_cue`; the shipped weights use both): world up
and the view ray, given in the points' frame, enter the encoder or end z; they rotate with the
points, so the equivariance above holds for (points, up, view ray) rotated together.

Internally vector features are channels-last (`[B, N, 3, C]`, see `vn.py`); the public z is
`[B, k, 3]` (k vectors), as in the paper.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from ndfa.io.atomic import atomic_path
from ndfa.core.errors import ModelError
from ndfa.ndf.vn import EPS, VNEdgeConv, VNLinear, VNResnetBlock, vn_invariant, vn_max_pool, vn_mean_pool

CODE_HEADS = ("norms", "gram")
CENTER_HEADS = ("linear", "gated")
POOLINGS = ("mean", "max")
DECODERS = ("dots", "frame")
# The frame decoder reads coordinates (and their squares, and offsets to nearby points) 10x the
# encoder's scale, i.e. in centimetres: a 3-8 mm wall then spans 0.3-0.8 input units, a step that
# freshly initialised ReLU layers resolve. Without this (and without local points) a 750-step run
# still predicted every validation query empty; with both, it predicted occupied ones by step 250.
DECODER_GAIN = 10.0


@dataclass(frozen=True)
class NDFConfig:
    """Model size and options. The defaults are sized for CPU training: on the project machine
    (2 cores) a training step of batch 32 x 400 points x 512 queries takes about 0.45 s and
    encoding one 1000-point view about 14 ms, with torch.set_num_threads(2).

    hidden: vector channels of the encoder's per-point features.
    latent: k, the number of vectors in z (NDF's latent is k x 3).
    knn: neighbours per point in the encoder's first, local layer (the point itself included).
        12 rather than NDF's 20: the local layer's cost grows with it, and torch.topk switches
        to a faster algorithm when 64 * knn <= points (768 for 12), which halves the neighbour
        search for a 1000-point view compared with 16.
    encoder_blocks: residual VN blocks, each seeing its input and the pooled (global) context.
    pooling: "mean" (as NDF) or "max" (VN max-pool: per channel the point furthest along a
        learned direction). With a zero-centred input the mean of anything linear in the points
        is zero, so mean pooling passes on only what the nonlinearities make; max learnt the mug's
        axis and center faster (`scripts/ndf_axis_study.py`, 200 steps: axis 53 vs 67 degrees,
        center 17 vs 20 mm). Mean is less sensitive to single outlying points.
    decoder: "dots" feeds the occupancy MLP |x|^2 and the dot products x . z_j; "frame" also
        gives it x in an orthonormal frame built from z (see `object_frame`): the object's own
        coordinates, in which a thin wall is a simple interval of radius and height; with "dots"
        the MLP must square the projections itself. Alone it made no difference in 500-step runs
        (both decoders still called every query empty); with `DECODER_GAIN` and `local_points` it
        learns occupancy (model card).
    local_points: with the "frame" decoder, each query also sees its offsets to this many nearest
        input points, in the object frame, and their lengths (0: off). The visible surface then
        places the wall it belongs to directly instead of through z; z must still complete the
        hidden side.
    decoder_width: width of the occupancy MLP.
    decoder_blocks: residual blocks of the occupancy MLP.
    code_head: "norms" is the paper's s_i = |z_i| (D = latent); "gram" feeds the Gram matrix of a
        learned projection of z (all its rotation invariants) through a small MLP (D = code_dim).
        The norms are all >= 0, so any two codes have a cosine similarity >= 0 and in short runs
        it sat above 0.9 for every pair; the gram code can point anywhere.
    code_dim: D of the "gram" shape code.
    gram_channels: m, the channels z is projected to before taking the m x m Gram matrix.
    up_cue: the encoder also gets the direction of gravity (up) in the input's frame, one vector
        that rotates with the points, so the model stays SO(3)-equivariant in (points, up) while
        knowing which way the mug stands: a mug's height and radius are then extents along and
        across a given axis instead of ones the network must first find from the points (the
        frame decoder's axis was still 15-17 degrees off after 11,000 steps without it). The
        detector knows up from the camera pose (world z); training tilts it by a few degrees.
    view_cue: z also ends with the unit vector from the camera to the view's centroid (the
        camera sits at the origin of the points' frame before centring): which side of the mug is
        visible, and so where the hidden half and the center lie. The decoder and the center head
        see it; the encoder and the shape code do not (see `Encoder`).
    center_head: "linear" maps z linearly to the center offset (one VN-linear channel); "gated"
        adds a combination of z's vectors weighted by an MLP of z's rotation invariants, so the
        offset can grow with the mug's size (equivariant: invariant weights times vectors).
    input_scale: fixed factor on the zero-centred metric input (and queries): 10 turns a
        6-13 cm mug into about unit size, the scale the layers are initialised for.
    gram_eps: the epsilon of the batch norm that standardises the Gram invariants. z is small
        (|z_i| ~ 0.06), so the invariants vary by ~1e-4.5 (variance ~1e-9): torch's default 1e-5
        then dominates the variance and shrinks the head's inputs ~30x. 1e-5 is what the first
        shipped weights were trained with; new runs use 1e-10.
    """

    hidden: int = 32
    latent: int = 64
    knn: int = 12
    encoder_blocks: int = 3
    pooling: str = "mean"
    decoder: str = "dots"
    local_points: int = 0
    decoder_width: int = 128
    decoder_blocks: int = 3
    code_head: str = "gram"
    code_dim: int = 64
    gram_channels: int = 16
    input_scale: float = 10.0
    gram_eps: float = 1e-5
    up_cue: bool = False
    view_cue: bool = False
    center_head: str = "linear"

    @property
    def cues(self) -> int:
        """How many direction cues (up, view ray) the encoder takes besides the points."""
        return int(self.up_cue) + int(self.view_cue)

    @property
    def code_dim_out(self) -> int:
        """D, the length of the shape code: code_dim, or with the "norms" head one per shape
        vector of z (all but the view ray)."""
        return self.code_dim if self.code_head == "gram" else self.latent - int(self.view_cue)

    def __post_init__(self) -> None:
        if self.code_head not in CODE_HEADS:
            raise ModelError(f"unknown code_head {self.code_head!r}; expected one of {CODE_HEADS}")
        if self.decoder not in DECODERS:
            raise ModelError(f"unknown decoder {self.decoder!r}; expected one of {DECODERS}")
        if self.local_points and self.decoder != "frame":
            raise ModelError("local_points needs the frame decoder (offsets are made invariant in its frame)")
        if self.center_head not in CENTER_HEADS:
            raise ModelError(f"unknown center_head {self.center_head!r}; expected one of {CENTER_HEADS}")
        if self.pooling not in POOLINGS:
            raise ModelError(f"unknown pooling {self.pooling!r}; expected one of {POOLINGS}")
        sizes = (self.hidden, self.latent, self.knn, self.decoder_width, self.code_dim, self.gram_channels)
        if min(sizes) < 1 or self.local_points < 0 or self.encoder_blocks < 0 or self.decoder_blocks < 0 or self.input_scale <= 0:
            raise ModelError(f"model sizes and input_scale must be positive: {self}")
        if self.latent <= self.cues + 1:
            raise ModelError(f"latent must exceed the {self.cues} direction cue(s) it holds by 2 or more")


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
        return self.to_latent(self.final_pool(x))  # [B, 3, latent - cues]


class ResnetBlockFC(nn.Module):
    """Plain residual MLP block, out = x + Linear(ReLU(Linear(ReLU(x)))), the last layer zero-init."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.linear_0 = nn.Linear(width, width)
        self.linear_1 = nn.Linear(width, width)
        nn.init.zeros_(self.linear_1.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.linear_1(torch.relu(self.linear_0(torch.relu(x))))


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
            h = h + self.local_in(self._nearest_offsets(queries, points - center.unsqueeze(1), frame))
        return self.out(torch.relu(self.blocks(h))).squeeze(-1)

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


class GramCode(nn.Module):
    """Shape code from all rotation invariants of z: `[B, 3, k] -> [B, code_dim]`.

    z is projected to m vectors; their m x m Gram matrix (upper triangle) fixes them up to a
    rotation, so it keeps everything about shape that a rotation-invariant code can keep.
    """

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
        return self.whiten(self.mlp(self.standardise(gram[:, self.upper[0], self.upper[1]])))


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
        nn.init.zeros_(self.weights[-1].weight)
        nn.init.zeros_(self.weights[-1].bias)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        invariants = vn_invariant(z, self.frame(z)).flatten(1)  # [B, k * frame]
        return self.linear(z) + z @ self.weights(invariants).unsqueeze(-1)  # [B, 3, 1], as VNLinear(k, 1)


class NDFModel(nn.Module):
    """Encoder, occupancy decoder, shape-code head and center head. Pure torch, no I/O.

    All metric inputs are zero-centred by the caller, in metres: `points` by their own centroid,
    `queries` by the same centroid. z lives in the scaled frame (its units are not metres).
    """

    def __init__(self, config: NDFConfig = NDFConfig()) -> None:
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        self.decoder = OccupancyDecoder(config)
        self.gram_code = GramCode(config) if config.code_head == "gram" else None
        self.center_head = VNLinear(config.latent, 1) if config.center_head == "linear" else GatedCenterHead(config)

    def encode(self, points: torch.Tensor, up: torch.Tensor | None = None,
               view_ray: torch.Tensor | None = None) -> torch.Tensor:
        """Zero-centred points `[B, N, 3]` (metres) -> z `[B, k, 3]`, rotating with the points.

        up: `[B, 3]` the direction of gravity opposed (world up) in the points' frame; view_ray:
        `[B, 3]` the vector from the camera to the points' centroid (the centroid itself, before
        centring, for points in the camera frame). Each is needed when the model was built with
        its cue (`NDFConfig.up_cue`, `view_cue`) and ignored otherwise; both are normalised here.
        """
        cues = self.cue_vectors(up, view_ray)  # [B, 3, cues]
        z = self.encoder(points * self.config.input_scale, cues[..., :1] if self.config.up_cue else None)
        if cues is not None:
            # z ends with the cues as given (up, then the view ray): the decoder and the center
            # head read them there; the shape code leaves the view ray out (`shape_code`).
            z = torch.cat([z, cues], dim=-1)
        return z.transpose(-1, -2)

    def cue_vectors(self, up: torch.Tensor | None, view_ray: torch.Tensor | None) -> torch.Tensor | None:
        """The unit direction cues this model takes, `[B, 3, cues]` (up first), or None."""
        wanted = [(name, value) for name, value, used in
                  (("up", up, self.config.up_cue), ("view_ray", view_ray, self.config.view_cue)) if used]
        missing = [name for name, value in wanted if value is None]
        if missing:
            raise ModelError(f"this model's encoder needs the direction cue(s) {', '.join(missing)}")
        if not wanted:
            return None
        return torch.stack([nn.functional.normalize(value, dim=-1) for _, value in wanted], dim=-1)

    def shape_code(self, z: torch.Tensor) -> torch.Tensor:
        """z `[B, k, 3]` -> rotation-invariant shape code `[B, D]` (D = latent or code_dim).

        Without the view ray, z's last vector with the view cue: how the camera looked is no part
        of the shape."""
        if self.config.view_cue:
            z = z[:, :-1]
        if self.gram_code is None:
            return z.norm(dim=-1)  # the paper's s_i = |z_i|
        return self.gram_code(z.transpose(-1, -2))

    def center_offset(self, z: torch.Tensor) -> torch.Tensor:
        """z `[B, k, 3]` -> predicted center of the full shape minus the input centroid `[B, 3]`, metres.

        A partial view's centroid sits on the visible side; this equivariant estimate moves it to
        the center of the whole object (the paper takes the mean of the reconstructed occupancy).
        """
        return self.center_head(z.transpose(-1, -2)).squeeze(-1) / self.config.input_scale

    def occupancy_logits(self, z: torch.Tensor, queries: torch.Tensor, points: torch.Tensor | None = None) -> torch.Tensor:
        """z `[B, k, 3]`, zero-centred queries `[B, Q, 3]` (metres) -> occupancy logits `[B, Q]`.
        `points`: the zero-centred input `[B, N, 3]` z was encoded from; needed with `local_points`."""
        scale = self.config.input_scale
        center = self.center_offset(z) * scale if self.decoder.use_frame else None
        return self.decoder(z.transpose(-1, -2), queries * scale, center, None if points is None else points * scale)

    def frame_vectors(self, z: torch.Tensor) -> torch.Tensor | None:
        """z `[B, k, 3]` -> the two vectors `[B, 3, 2]` the "frame" decoder builds its frame from
        (training aligns them with the mug's axis and handle), or None for the "dots" decoder."""
        return self.decoder.frame(z.transpose(-1, -2)) if self.decoder.use_frame else None

    def forward(self, points: torch.Tensor, queries: torch.Tensor, up: torch.Tensor | None = None,
                view_ray: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        z = self.encode(points, up, view_ray)
        out = {
            "z": z,
            "shape_code": self.shape_code(z),
            "center_offset": self.center_offset(z),
            "occupancy_logits": self.occupancy_logits(z, queries, points),
        }
        frame_vectors = self.frame_vectors(z)
        return out if frame_vectors is None else out | {"frame_vectors": frame_vectors}


def save_checkpoint(path: str | Path, model: NDFModel, config: NDFConfig, extra: dict | None = None) -> None:
    """Write `{"config", "state_dict", **extra}` with torch.save, atomically.

    `extra` (e.g. step, losses, the training config) must hold only what a weights-only load accepts
    (`load_model` uses weights_only=True): tensors, numbers, strings, lists, tuples, dicts of them.
    The file is written next to `path` and renamed over it, so a crash never leaves half a file.
    """
    extra = dict(extra or {})
    clash = {"config", "state_dict"} & extra.keys()
    if clash:
        raise ValueError(f"extra may not use the reserved keys {sorted(clash)}")
    with atomic_path(path) as temporary:
        torch.save({"config": dataclasses.asdict(config), "state_dict": model.state_dict(), **extra}, temporary)


def load_model(path: str | Path) -> tuple[NDFModel, dict]:
    """Load a checkpoint written by `save_checkpoint`: (model in eval mode, the extra entries).

    Raises ModelError naming the file if it is missing, unreadable or not an ndfa checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: checkpoint not found")
    try:
        content = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as exc:  # truncated, not a torch file, or holds objects beyond plain data
        raise ModelError(f"{path}: cannot read checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(content, dict) or not {"config", "state_dict"} <= content.keys():
        raise ModelError(f"{path}: not an ndfa checkpoint (no 'config' and 'state_dict' entries)")
    try:
        # Checkpoints from before the "decoder" option had the "dots" decoder, without local points.
        model = NDFModel(NDFConfig(**({"decoder": "dots", "local_points": 0} | content["config"])))
        model.load_state_dict(content["state_dict"])
    except (TypeError, RuntimeError, ModelError) as exc:  # unknown config keys, mismatched weights
        raise ModelError(f"{path}: checkpoint does not match this model ({exc})") from exc
    extra = {key: value for key, value in content.items() if key not in ("config", "state_dict")}
    return model.eval(), extra
