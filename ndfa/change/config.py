"""The change detector's parameters: the paper's (Sec. IV, V-C), and ndfa's additions beside them.

`DetectorConfig` holds three parts with the paper's own parameters (`association`, `registration`,
`decision`) and one part per addition of ndfa's (`levels`, `views`, `drift`, `ransac`, `priors`,
`waiting`, `evidence`, `rotation`). Every knob of an addition says at its field the value that switches it
off; `DetectorConfig.paper()` is the paper's parameters with every addition off. Why each default
differs from the paper's, what was measured to choose it, and what each addition does on the
seven masked scenes: `docs/detector.md`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

Fusion = Literal["mean", "best"]


# -- the paper's parameters ------------------------------------------------------------------------


@dataclass(frozen=True)
class AssociationConfig:
    """Intra-session association (Sec. IV-A): measurements -> the objects of one session."""

    tree_length_m: float = 1.2        # l: interval length of the object trees (paper: 1.2 m sim, 1.6 m real)
    distance_m: float = 0.05          # delta_d: largest center distance of a measurement to its object (paper 0.02)
    shape_similarity: float = 0.35    # delta_s: smallest cosine similarity of two codes of one object (paper 0.9; tuned by replay for NDF v2, docs/detector.md)


@dataclass(frozen=True)
class RegistrationConfig:
    """T_rel, target world -> source world (Sec. IV-B): SVD + RANSAC on shape-matched object pairs."""

    pairs: int = 6                # N: target objects with a shape match before the first attempt
    inlier_m: float = 0.05        # a registered pair this close supports a transform (the paper gives no value)
    seed: int = 0                 # RANSAC's sampling


@dataclass(frozen=True)
class DecisionConfig:
    """The change test of a target object (Sec. IV-B, Fig. 5)."""

    edge_m: float = 0.03               # delta_e: largest difference of two corresponding graph edges
    fallback_distance_m: float = 0.05  # a lone object is unchanged this close to its shape match (the paper: no value)


# -- ndfa's additions, each with its "off" ---------------------------------------------------------


@dataclass(frozen=True)
class LevelsConfig:
    """Objects on surfaces above one another (`ndfa.change.tree`: a third interval tree, T_z)."""

    # h: the interval length of T_z, metres: objects whose centers are this far apart in height or
    # more are never in one cell (not neighbours, not association candidates), and a measurement
    # joins an object by `ViewsConfig.same_place_m` only within h / 2 in height. Shelves stand
    # 25 cm or more apart, and the centers of a category's objects on one surface lie within a few
    # cm of each other (docs/shelves.md). Off: None (the paper's tree: a cell is a column).
    tree_height_m: float | None = 0.2

    def __post_init__(self) -> None:
        if self.tree_height_m is not None and not self.tree_height_m > 0:
            raise ValueError(f"levels tree_height_m must be positive or None, got {self.tree_height_m}")


@dataclass(frozen=True)
class ViewsConfig:
    """One object from many views (`ndfa.change.associate`)."""

    same_place_m: float = 0.03   # a measurement this close (horizontally) to an object is that object. Off: 0
    fusion: Fusion = "mean"      # an object's code and center: its measurements' "mean" (median center). Off: "best" (the paper's: the most confident measurement)

    def __post_init__(self) -> None:
        if self.fusion not in ("best", "mean"):
            raise ValueError(f"fusion must be 'best' or 'mean', got {self.fusion!r}")


@dataclass(frozen=True)
class DriftConfig:
    """Allowances for poses that drift between the views of a place (docs/detector.md, "Drift")."""

    revisit_m: float = 0.12      # an object this close (horizontally and in height), not measured in the same frame, takes the measurement. Off: 0
    across_cells: bool = True    # association candidates also from the cells across an edge within reach. Off: False (the cell only)
    # The position tests of `DecisionConfig` and `EvidenceConfig.in_place_m` widen by this many times
    # the two objects' combined center scatter (`SessionObject.center_scatter_m`): about 0.5 cm in
    # simulation, 4 cm on a real sequence with estimated poses. Off: 0 (fixed distances).
    scatter_factor: float = 1.0
    # A target object registered this close to a source cell's edge is compared with the objects
    # across it too (T_rel errs by centimetres where the odometry drifted). Off: 0 (the cell it lands in).
    cell_margin_m: float = 0.05
    # A measurement near where an object was last measured (by the association's own distances,
    # `same_place_m` or `distance_m` with alike codes) joins it as one near its center does: the
    # odometry drifts little from one frame to the next, and an object followed while the drift
    # carries its views past `revisit_m` from their median stays one object. Off: False (the center only)
    follow_latest: bool = True


@dataclass(frozen=True)
class RansacConfig:
    """How RANSAC's T_rel is tried and accepted (`ndfa.change.registrar`)."""

    candidates: int = 10          # shape matches per target object offered to RANSAC. Off: 1 (the paper's best match)
    min_inliers: int = 4          # inliers needed to accept T_rel; until then nothing is decided. Off: 0 (whatever RANSAC returns)
    enough_inliers: int = 12      # T_rel is re-estimated as target objects arrive until it has this many. Off: 0 (never)
    retry_frames: int = 10        # before T_rel exists: an attempt per new target object, else every this many frames. Off: 1
    # A source map with fewer than N objects registers with all of them. Off: False (it waits for N)
    small_maps: bool = True


@dataclass(frozen=True)
class PriorConfig:
    """Scene-level T_rel hypotheses (the shared world, the scene alignment: `ndfa.run.align`), which
    the object pairs verify (`ndfa.change.register.verify_prior`). Fewer agreeing pairs accept one
    than a RANSAC fit, since a prior is not fitted to them; the pairs near it refine it first."""

    enabled: bool = True          # the registrar takes the priors a run offers. Off: False (object pairs alone; a run computes none)
    min_inliers: int = 2          # inliers needed to accept a prior
    support_m: float = 0.10       # pairs this close to where a prior puts them refine it (its own error)


@dataclass(frozen=True)
class WaitingConfig:
    """When a verdict is reported (`ndfa.change.policy`, `ndfa.change.verdict`)."""

    min_measurements: int = 3      # an object is tested (and reported) only from this many measurements. Off: 1
    # ... or from one measurement and sightings (views too small to encode: `ndfa.change.sightings`)
    # making up the rest: an object sighted in many frames is no fragment of one view (unless
    # another object stands in its place); and a session's sightings that none of its objects is
    # withhold a change at their place (docs/detector.md, "Sightings"). Off: False (measurements only).
    sightings: bool = True
    confirm_measurements: int = 8  # a "changed" verdict on fewer measurements waits for more views. Off: 1
    # A target object alone in its target neighbourhood while the source's has company, or one whose
    # graph agrees with no match while it has fewer neighbours than the match, waits (decided at the
    # end at the latest). Off: False (decided at once).
    neighbours: bool = True
    # A "changed" verdict on a target object with a source object standing in its place (within
    # `EvidenceConfig.in_place_m` and the scatter slack) rests on the codes alone, and codes of one
    # object seen from unlike sides can disagree: it waits for every view (decided at the end of the
    # target). Off: False (decided as any other).
    in_place: bool = True


@dataclass(frozen=True)
class EvidenceConfig:
    """What counts as a match or as looked at, beyond the paper's tests."""

    in_place_m: float = 0.05           # no edge agrees, yet unchanged this close to its shape match. Off: 0
    # A source object counts as looked at by the target (and so "removed" when never matched) when a
    # tested target object stands in its neighbourhood AND within this height of it: the paper's
    # trees are horizontal (without `LevelsConfig`'s T_z), so without it testing a mug on a table "observes" a piece of floor under the
    # table, which the target may never have seen. Off: 0 (any height).
    observed_height_m: float = 0.3
    # ... or when a tested target object stands within this distance of it horizontally, in another
    # cell: a cell's edge may cut a board or a table between two mugs the same views saw, and the
    # smaller cells of T_z (`LevelsConfig`) leave a mug alone in its cell more often (docs/shelves.md).
    # l/2 (`tree_length_m` 1.2): a neighbourhood of about a cell's size, centred on the tested object
    # instead of cut where the first centers fell (0.3 missed a planted kitchen removal 42 cm from
    # the one tested object near it: docs/plant.md). Off: 0 (the cell only).
    observed_reach_m: float = 0.6
    # A changed target object is reported "moved" from a removed source object only when their codes
    # agree this well: a move needs the same object at both ends, and delta_s (0.35) lets different
    # mugs pair. Every same-mug pair of the seven masked scenes is above 0.859 (docs/registration.md,
    # "The right kind"); below it, removed + added. Off: None (delta_s, the paper's)
    move_similarity: float | None = 0.85
    # An "added" object's place must have been shown by the source's frames, a removed one's by the
    # target's, well enough for perception to take an object of this size standing there (in view
    # whole, in range, its pixels not hidden reaching perception's minimum: `ndfa.change.sight`);
    # otherwise the change is withheld with the reason. The size of a large mug, 10 cm across and
    # 11 cm tall (about 1.5x the median mug's pixels in the simulator's masks): withheld only where
    # even such a mug would have fallen short, 3.5 m away at 615 px focal length (docs/detector.md).
    # Off: radius 0.
    sight_radius_m: float = 0.05
    sight_height_m: float = 0.11
    # ... for the object claimed, where its own views show it smaller than a median mug, a cylinder
    # of this radius and height (about the median mug's pixels in the masks; the large one above is
    # about their 90th percentile): its expected pixels are the large mug's times that share
    # (`ndfa.change.sight.own_size`), so that a cup's place seen from where a mug would just have
    # shown is not taken as shown. Off: None (every object as a large mug).
    sight_typical_m: tuple[float, float] | None = (0.04, 0.09)
    # ... and seen empty there: a place whose depth ended on something standing in it (most of the
    # frames that showed it well), with no object of that session's map there to be what stood in
    # it, was not seen empty, and the change is withheld with the reason (`ndfa.change.sight`,
    # docs/detector.md). Off: False (shown is enough).
    seen_empty: bool = True
    # ... nor where that session's map holds an object in the place measured at least this many
    # times but too few to be tested: something object-like stood there, whatever the frames read of
    # the place (a cup narrower and shorter than the place's cylinder reads "seen through"); one view
    # may be a stray segment or a piece of a neighbour (raw textured seed 1's moved mug's new place
    # held such a source object). Off: 0.
    glimpse_views: int = 2
    # Two sessions' views of an object are from a common side when their directions from the object
    # about up lie within this many degrees (`ndfa.change.sides`): the NDF's codes and handle
    # headings depend on the side seen. A turn ("rotated") is measured between the views from a
    # common side, and one seen from none needs `RotationConfig.opposite_sides_factor` times the
    # bar; an "added" object standing where another stood, their codes compared across no common
    # side and not unrelated (`doubtful_share`), is withheld as doubtful (docs/shelves.md).
    # A quarter turn: beyond it a view sees mostly what the other could not. Off: None.
    side_deg: float | None = 90.0
    # ... "not unrelated": a cosine above this share of delta_s (`AssociationConfig.shape_similarity`),
    # halfway from unrelated codes (about 0: different mugs' median -0.05 on `shelves`) to the bar of
    # the same object. One object's codes from opposite sides were measured down to 0.35 (`shelves`,
    # object means) and 0.17 (the kitchen's white mug, means of four views; docs/detector.md, "Drift").
    doubtful_share: float = 0.5
    # Two objects that swapped places: a target object consistent with the source object in its
    # place, but whose code is this much nearer another source object around it, while a target
    # object standing in that one's place is this much nearer the first: each is more like the other's
    # source object than like its own place's, so they switched (a bowl and a mug-like bowl a hand
    # apart; delta_s, 0.35, lets most such pairs through as unchanged). One object's codes across
    # two sessions spread by about 0.1 (the same mug: median 0.97, lowest 0.86; docs/registration.md,
    # "The right kind"), and twins stay within it. Off: None.
    swap_margin: float | None = 0.1


@dataclass(frozen=True)
class RotationConfig:
    """Rotated objects (`ndfa.change.rotation`, docs/rotation.md; the paper has no such test)."""

    # An object found unchanged whose handle turned about up by more than this many degrees is
    # reported "rotated". Off: None.
    threshold_deg: float | None = 30.0
    # A view's handle heading counts from this strength (the horizontal length of the NDF's handle
    # vector, `ndfa.ndf.heading`), weighted by it: with the shipped NDF v2, 57 % of the views of
    # three baseline scenes reach 0.10, and 93 % of those are within 20 degrees of the truth.
    heading_strength: float = 0.10
    views: int = 3                 # reliable views each of the two objects needs
    spread_deg: float = 25.0       # their headings' circular spread, per object, at most this
    # The turn must pass `threshold_deg` by this many times the two objects' spreads combined
    # (sqrt(s_t^2 + s_s^2)): their headings' view-dependent bias does not average away. Off: 0.
    margin: float = 1.0
    # A turn seen from no common side (`EvidenceConfig.side_deg`: the source from the front, the
    # target from behind) must pass `threshold_deg` this many times over: a heading's view-dependent
    # bias reverses with the side, so the two sessions' biases add instead of cancelling
    # (docs/shelves.md). Below it the turn is withheld as doubtful. Off: 1.
    opposite_sides_factor: float = 2.0
    # Both objects need at least this part of their views' category probability on categories
    # with a handle (`CATEGORIES_WITH_HEADING`): a box named "mug" by a plurality of its views
    # (0.43 mug against 0.33 box) has no handle whose turn could show. 0.5: more likely than not.
    # Objects of unknown category (a model without a category head) are tested as mugs. Off: 0.
    handle_share: float = 0.5

    def __post_init__(self) -> None:
        if self.threshold_deg is not None and not 0.0 < self.threshold_deg < 180.0:
            raise ValueError(f"rotation threshold_deg must be in (0, 180) degrees or None, got {self.threshold_deg}")


ADDITIONS = ("levels", "views", "drift", "ransac", "priors", "waiting", "evidence", "rotation")


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of the change detector; the default is ndfa's tuning for the shipped NDF."""

    association: AssociationConfig = field(default_factory=AssociationConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    levels: LevelsConfig = field(default_factory=LevelsConfig)
    views: ViewsConfig = field(default_factory=ViewsConfig)
    drift: DriftConfig = field(default_factory=DriftConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    priors: PriorConfig = field(default_factory=PriorConfig)
    waiting: WaitingConfig = field(default_factory=WaitingConfig)
    evidence: EvidenceConfig = field(default_factory=EvidenceConfig)
    rotation: RotationConfig = field(default_factory=RotationConfig)

    @classmethod
    def paper(cls) -> DetectorConfig:
        """The paper's parameters (Sec. V-C, simulation) with every addition off (`additions_off`).
        `docs/detector.md` lists the rules that stay (they have no knob) and the two values the
        paper does not give (the RANSAC inlier distance and the lone-object distance)."""
        paper = cls(association=AssociationConfig(tree_length_m=1.2, distance_m=0.02, shape_similarity=0.9),
                    registration=RegistrationConfig(pairs=6, inlier_m=0.05, seed=0),
                    decision=DecisionConfig(edge_m=0.03, fallback_distance_m=0.05))
        return paper.without(*ADDITIONS)

    def without(self, *additions: str) -> DetectorConfig:
        """This config with the named additions (`ADDITIONS`) switched off, the others as they are."""
        unknown = set(additions) - set(ADDITIONS)
        if unknown:
            raise ValueError(f"unknown additions {sorted(unknown)}; they are {', '.join(ADDITIONS)}")
        off = {"levels": LevelsConfig(tree_height_m=None),
               "views": ViewsConfig(same_place_m=0.0, fusion="best"),
               "drift": DriftConfig(revisit_m=0.0, across_cells=False, scatter_factor=0.0, cell_margin_m=0.0,
                                     follow_latest=False),
               "ransac": RansacConfig(candidates=1, min_inliers=0, enough_inliers=0, retry_frames=1, small_maps=False),
               "priors": PriorConfig(enabled=False),
               "waiting": WaitingConfig(min_measurements=1, confirm_measurements=1, neighbours=False, in_place=False,
                                        sightings=False),
               "evidence": EvidenceConfig(in_place_m=0.0, observed_height_m=0.0, observed_reach_m=0.0, move_similarity=None,
                                            sight_radius_m=0.0, seen_empty=False, side_deg=None, swap_margin=None),
               "rotation": RotationConfig(threshold_deg=None)}
        values = {name: getattr(self, name) for name in ("association", "registration", "decision") + ADDITIONS}
        return DetectorConfig(**(values | {name: off[name] for name in additions}))
