"""The NDF model's size and options (`NDFConfig`) and the values each option may take."""

from __future__ import annotations

from dataclasses import dataclass

from ndfa.core.errors import ModelError

CODE_HEADS = ("norms", "gram")
CENTER_HEADS = ("linear", "gated")
POOLINGS = ("mean", "max")
DECODERS = ("dots", "frame")


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
        axis and center faster (`studies/ndf_axis_study.py`, 200 steps: axis 53 vs 67 degrees,
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
    center_refits: gated center heads refitted on a trained encoder (`ndfa train --train-only
        center_refit --center-refits K`), each from its own random start on its own center loss;
        their mean is the model's center (their errors are partly independent). The decoder keeps
        the center head it was trained with as its frame's origin (`NDFModel.frame_origin`), so
        refitting the center leaves every occupancy as it was. 0: the center head is the center.
    categories: the object categories (names) a classification head on the shape code tells
        apart (`heads.CategoryHead`, NDF v3; docs/ndf.md says why a head and not the nearest
        category prototype); empty (the default, NDF v2): no head.
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
    center_refits: int = 0
    categories: tuple[str, ...] = ()

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
        # A checkpoint's config comes back from torch's loader with lists where tuples were.
        object.__setattr__(self, "categories", tuple(self.categories))
        if len(self.categories) == 1 or len(set(self.categories)) != len(self.categories):
            raise ModelError(f"categories must be two or more distinct names (or none), got {self.categories}")
        if self.code_head not in CODE_HEADS:
            raise ModelError(f"unknown code_head {self.code_head!r}; expected one of {CODE_HEADS}")
        if self.decoder not in DECODERS:
            raise ModelError(f"unknown decoder {self.decoder!r}; expected one of {DECODERS}")
        if self.local_points and self.decoder != "frame":
            raise ModelError("local_points needs the frame decoder (offsets are made invariant in its frame)")
        if self.center_head not in CENTER_HEADS:
            raise ModelError(f"unknown center_head {self.center_head!r}; expected one of {CENTER_HEADS}")
        if self.center_refits < 0:
            raise ModelError(f"center_refits must be >= 0, got {self.center_refits}")
        if self.pooling not in POOLINGS:
            raise ModelError(f"unknown pooling {self.pooling!r}; expected one of {POOLINGS}")
        sizes = (self.hidden, self.latent, self.knn, self.decoder_width, self.code_dim, self.gram_channels)
        if min(sizes) < 1 or self.local_points < 0 or self.encoder_blocks < 0 or self.decoder_blocks < 0 or self.input_scale <= 0:
            raise ModelError(f"model sizes and input_scale must be positive: {self}")
        if self.latent <= self.cues + 1:
            raise ModelError(f"latent must exceed the {self.cues} direction cue(s) it holds by 2 or more")
