"""The change detector's parameters, one frozen sub-config per step of the paper's Sec. IV.

`DetectorConfig()` holds ndfa's defaults, `DetectorConfig.paper()` the paper's own parameters
(Sec. V-C). Why each default differs from the paper's, and what was measured to choose it, is in
`docs/detector.md`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

Fusion = Literal["mean", "best"]


@dataclass(frozen=True)
class AssociationConfig:
    """Intra-session association (Sec. IV-A): measurements -> the objects of one session."""

    tree_length_m: float = 1.2        # l: interval length of the object trees (paper: 1.2 m sim, 1.6 m real)
    distance_m: float = 0.05          # delta_d: largest center distance of a measurement to its object (paper 0.02)
    shape_similarity: float = 0.35    # delta_s: smallest cosine similarity of two codes of one object (paper 0.9; tuned by replay for NDF v2, docs/detector.md)
    same_place_m: float = 0.03        # a measurement this close (horizontally) to an object is that object; 0: off
    fusion: Fusion = "mean"           # an object's code and center: its measurements' "mean" (median center) or the "best"
    revisit_m: float = 0.12           # an alike object this close, not measured in the same frame, takes it (drift); 0: off
    across_cells: bool = True         # candidates also from the cells across an edge within reach; False: the cell only

    def __post_init__(self) -> None:
        if self.fusion not in ("best", "mean"):
            raise ValueError(f"fusion must be 'best' or 'mean', got {self.fusion!r}")


@dataclass(frozen=True)
class RegistrationConfig:
    """T_rel, target world -> source world (Sec. IV-B), from objects matched by shape.

    Prior hypotheses (`ndfa.change.register.RegistrationPrior`) are not fitted to the pairs, so
    fewer agreeing pairs accept one than a RANSAC fit; the pairs near it refine it first."""

    pairs: int = 6                # N: target objects with a shape match before the first attempt
    candidates: int = 10          # shape matches per target object offered to RANSAC (paper 1)
    inlier_m: float = 0.05        # a registered pair this close supports a transform
    min_inliers: int = 4          # inliers needed to accept T_rel; until then nothing is decided
    enough_inliers: int = 12      # T_rel is re-estimated as target objects arrive until it has this many
    retry_frames: int = 10        # before T_rel exists: an attempt per new target object, else every this many frames
    seed: int = 0                 # RANSAC's sampling
    prior_min_inliers: int = 2    # inliers needed to accept a prior hypothesis (shared world, scene alignment)
    prior_support_m: float = 0.10  # pairs this close to where a prior puts them refine it (its own error)


@dataclass(frozen=True)
class DecisionConfig:
    """The change test of a target object (Sec. IV-B) and when its verdict is reported."""

    edge_m: float = 0.03               # delta_e: largest difference of two corresponding graph edges
    fallback_distance_m: float = 0.05  # a lone object is unchanged this close to its shape match
    in_place_m: float = 0.05           # no edge agrees, yet unchanged this close to its shape match; 0: off
    # The two position tests above widen by this many times the two objects' combined center
    # scatter (`SessionObject.center_scatter_m`): about 0.5 cm in simulation, 4 cm on a real sequence
    # with estimated poses (docs/detector.md). 0: fixed distances (paper).
    scatter_factor: float = 1.0
    # T_rel errs by centimetres where the odometry drifted: a target object registered this close to
    # a source cell's edge is compared with the objects across it too. 0: the cell it lands in (paper).
    cell_margin_m: float = 0.05
    min_measurements: int = 3          # an object is tested (and reported) only from this many measurements
    confirm_measurements: int = 8      # a "changed" verdict on fewer measurements waits for more views
    # A source object counts as looked at by the target (and so "removed" when never matched) when a
    # tested target object stands in its neighbourhood AND within this height of it: the trees are
    # horizontal, so without it testing a mug on a table "observes" a piece of floor under the
    # table, which the target may never have seen (docs/detector.md). 0: off (any height).
    observed_height_m: float = 0.3
    # Rotated objects (`ndfa.change.rotation`, docs/rotation.md): an object found unchanged whose
    # handle turned about up by more than this many degrees between the sessions is reported
    # "rotated". None: off (the paper has no such test).
    rotation_deg: float | None = 30.0
    # A view's handle heading counts from this strength (the horizontal length of the NDF's handle
    # vector, `ndfa.ndf.heading`), weighted by it: with the shipped NDF v2, 57 % of the views of
    # three baseline scenes reach 0.10, and 93 % of those are within 20 degrees of the truth
    # (docs/rotation.md).
    heading_strength: float = 0.10
    rotation_views: int = 3            # reliable views each of the two objects needs
    rotation_spread_deg: float = 25.0  # their headings' circular spread, per object, at most this
    # The turn must pass `rotation_deg` by this many times the two objects' spreads combined
    # (sqrt(s_t^2 + s_s^2)): their headings' view-dependent bias does not average away. 0: off.
    rotation_margin: float = 1.0

    def __post_init__(self) -> None:
        if self.rotation_deg is not None and not 0.0 < self.rotation_deg < 180.0:
            raise ValueError(f"rotation_deg must be in (0, 180) degrees or None, got {self.rotation_deg}")


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of the change detector; the default is ndfa's tuning for the shipped NDF."""

    association: AssociationConfig = field(default_factory=AssociationConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)

    @classmethod
    def paper(cls) -> DetectorConfig:
        """The paper's parameters (Sec. V-C, simulation), with ndfa's additions switched off where a
        knob can: see `docs/detector.md` for the rules that stay (they have no knob) and for the two
        values the paper does not give (the RANSAC inlier distance and the lone-object distance)."""
        return cls(
            association=AssociationConfig(tree_length_m=1.2, distance_m=0.02, shape_similarity=0.9, same_place_m=0.0,
                                          fusion="best", revisit_m=0.0, across_cells=False),
            registration=RegistrationConfig(pairs=6, candidates=1, inlier_m=0.05, min_inliers=0, enough_inliers=0,
                                            retry_frames=1, seed=0),
            decision=DecisionConfig(edge_m=0.03, fallback_distance_m=0.05, in_place_m=0.0, scatter_factor=0.0,
                                    cell_margin_m=0.0,
                                    min_measurements=1,
                                    confirm_measurements=1, observed_height_m=0.0, rotation_deg=None),
        )
