"""The Neural Descriptor Field model (Simeonov et al., ICRA 2022) as used by Fu et al. (IROS 2022).

    encoder      f(P) = z              partial point cloud [B, N, 3] -> k vectors z [B, k, 3]
    decoder      Phi(x, z)             occupancy logit of query points x [B, Q, 3]
    shape code   s(z)                  rotation-invariant descriptor of the full shape [B, D]
    center head  t(z)                  offset of the full shape's center from the input's centroid
    category     c(s)                  with `NDFConfig.categories`: category logits from the code

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

This module assembles the model; its parts are the encoder network (`encoder_net`), the decoder
(`decoder`) and the heads (`heads`), its options `NDFConfig` (`config`).
"""

from __future__ import annotations

import torch
from torch import nn

from ndfa.core.errors import ModelError
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.decoder import OccupancyDecoder
from ndfa.ndf.encoder_net import Encoder
from ndfa.ndf.heads import CategoryHead, CenterHeadEnsemble, GatedCenterHead, GramCode
from ndfa.ndf.vn import VNLinear


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
        self.center_refit = CenterHeadEnsemble(config) if config.center_refits else None
        self.category_head = CategoryHead(config) if config.categories else None

    def encode(self, points: torch.Tensor, up: torch.Tensor | None = None,
               view_ray: torch.Tensor | None = None) -> torch.Tensor:
        """Zero-centred points `[B, N, 3]` (metres) -> z `[B, k, 3]`, rotating with the points.

        up: `[B, 3]` the direction of gravity opposed (world up) in the points' frame; view_ray:
        `[B, 3]` the vector from the camera to the points' centroid (the centroid itself, before
        centring, for points in the camera frame). Each is needed when the model was built with
        its cue (`NDFConfig.up_cue`, `view_cue`) and ignored otherwise; both are normalised here.
        """
        cues = self.cue_vectors(up, view_ray)  # [B, 3, cues]
        unit_up = cues[..., :1] if cues is not None and self.config.up_cue else None  # cues is set with up_cue
        z = self.encoder(points * self.config.input_scale, unit_up)
        if cues is not None:
            # z ends with the cues as given (up, then the view ray): the decoder and the center
            # head read them there; the shape code leaves the view ray out (`shape_code`).
            z = torch.cat([z, cues], dim=-1)
        z_vectors: torch.Tensor = z.transpose(-1, -2)
        return z_vectors

    def cue_vectors(self, up: torch.Tensor | None, view_ray: torch.Tensor | None) -> torch.Tensor | None:
        """The unit direction cues this model takes, `[B, 3, cues]` (up first), or None."""
        wanted = [(name, value) for name, value, used in
                  (("up", up, self.config.up_cue), ("view_ray", view_ray, self.config.view_cue)) if used]
        missing = [name for name, value in wanted if value is None]
        if missing:
            raise ModelError(f"this model's encoder needs the direction cue(s) {', '.join(missing)}")
        if not wanted:
            return None
        # (`value is not None` always holds here: missing cues were refused above.)
        unit_cues = [nn.functional.normalize(value, dim=-1) for _, value in wanted if value is not None]
        return torch.stack(unit_cues, dim=-1)

    def shape_code(self, z: torch.Tensor) -> torch.Tensor:
        """z `[B, k, 3]` -> rotation-invariant shape code `[B, D]` (D = latent or code_dim).

        Without the view ray, z's last vector with the view cue: how the camera looked is no part
        of the shape."""
        if self.config.view_cue:
            z = z[:, :-1]
        code: torch.Tensor
        if self.gram_code is None:
            code = z.norm(dim=-1)  # the paper's s_i = |z_i|
        else:
            code = self.gram_code(z.transpose(-1, -2))
        return code

    def category_logits(self, code: torch.Tensor) -> torch.Tensor:
        """Shape code `[B, D]` -> logits `[B, len(config.categories)]` of the object's category;
        ModelError for a model without categories (NDF v2)."""
        if self.category_head is None:
            raise ModelError("this model has no category head (NDFConfig.categories is empty)")
        logits: torch.Tensor = self.category_head(code)
        return logits

    def center_offset(self, z: torch.Tensor) -> torch.Tensor:
        """z `[B, k, 3]` -> predicted center of the full shape minus the input centroid `[B, 3]`, metres.

        A partial view's centroid sits on the visible side; this equivariant estimate moves it to
        the center of the whole object (the paper takes the mean of the reconstructed occupancy).
        """
        if self.center_refit is not None:  # the refitted heads' mean (`NDFConfig.center_refits`)
            return self.center_offset_members(z).mean(0)
        return self.frame_origin(z)

    def frame_origin(self, z: torch.Tensor) -> torch.Tensor:
        """The center head's offset `[B, 3]` (metres): the origin of the frame decoder's queries, as
        it was trained; the model's center too unless it has refitted heads."""
        offset: torch.Tensor = self.center_head(z.transpose(-1, -2)).squeeze(-1) / self.config.input_scale
        return offset

    def center_offset_members(self, z: torch.Tensor) -> torch.Tensor:
        """`[K, B, 3]`: each refitted head's offset (`NDFConfig.center_refits`), or the center head's
        alone (K = 1): what the center loss is taken over."""
        if self.center_refit is None:
            return self.frame_origin(z).unsqueeze(0)
        members: torch.Tensor = self.center_refit.each(z.transpose(-1, -2)).squeeze(-1) / self.config.input_scale
        return members

    def occupancy_logits(self, z: torch.Tensor, queries: torch.Tensor, points: torch.Tensor | None = None) -> torch.Tensor:
        """z `[B, k, 3]`, zero-centred queries `[B, Q, 3]` (metres) -> occupancy logits `[B, Q]`.
        `points`: the zero-centred input `[B, N, 3]` z was encoded from; needed with `local_points`."""
        scale = self.config.input_scale
        center = self.frame_origin(z) * scale if self.decoder.use_frame else None
        logits: torch.Tensor = self.decoder(z.transpose(-1, -2), queries * scale, center,
                                            None if points is None else points * scale)
        return logits

    def frame_vectors(self, z: torch.Tensor) -> torch.Tensor | None:
        """z `[B, k, 3]` -> the two vectors `[B, 3, 2]` the "frame" decoder builds its frame from
        (training aligns them with the mug's axis and handle), or None for the "dots" decoder."""
        return self.decoder.frame(z.transpose(-1, -2)) if self.decoder.use_frame else None

    def forward(self, points: torch.Tensor, queries: torch.Tensor, up: torch.Tensor | None = None,
                view_ray: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        z = self.encode(points, up, view_ray)
        code = self.shape_code(z)
        out = {
            "z": z,
            "shape_code": code,
            "center_offset": self.center_offset(z),
            "occupancy_logits": self.occupancy_logits(z, queries, points),
        }
        frame_vectors = self.frame_vectors(z)
        if frame_vectors is not None:
            out["frame_vectors"] = frame_vectors
        if self.category_head is not None:
            out["category_logits"] = self.category_logits(code)
        return out
