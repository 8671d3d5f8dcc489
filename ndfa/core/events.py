"""What the pipeline tells its sinks: one dataclass per kind of intermediate result.

The method's core (perception, NDF encoding, change detection) returns these instead of writing
anything; `ndfa.log` turns them into Rerun entities and Polars rows. Frames: `*_world` is the
session's own world frame; `*_source` is the source world (target points registered with T_rel).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ndfa.core.conventions import UNKNOWN_CATEGORY
from ndfa.core.frame import Frame

Session = Literal["source", "target"]
SESSIONS: tuple[Session, Session] = ("source", "target")  # a pair's two sessions, in pass order
DecisionKind = Literal["unchanged", "added", "removed", "moved", "rotated"]
GraphMode = Literal["graph", "in place", "fallback"]
# Where a T_rel came from: RANSAC on shape-matched object pairs (the paper's), or a prior hypothesis
# the pairs verified: the sessions' shared world, or the alignment of their scene clouds; or either
# accepted on the static scene's own evidence where too few pairs could verify it
# (`ndfa.run.scene_evidence`).
RegistrationMethod = Literal["object pairs", "shared world", "scene alignment", "scene (own evidence)",
                             "shared world (own evidence)"]
# The decision score at and above which the detector reports a change (`DecisionEvent.score`).
CHANGE_SCORE = 0.5


@dataclass(frozen=True, kw_only=True)
class FrameEvent:
    """A frame entered the pipeline (sinks may log its images and camera)."""

    session: Session
    frame: Frame


@dataclass(frozen=True, kw_only=True)
class ObservationEvent:
    """One instance of a frame: its cleaned partial cloud and what the NDF made of it, or why it was skipped."""

    session: Session
    frame_index: int
    instance_id: int
    n_pixels: int
    skipped: str | None                      # the reason, or None when encoded
    n_points: int = 0
    touches_border: bool = False
    points_world: np.ndarray | None = None   # (N, 3) the cleaned partial cloud
    shape_code: np.ndarray | None = None     # (D,)
    center_world: np.ndarray | None = None   # (3,)
    mean_occupancy: float = float("nan")
    reconstruction_world: np.ndarray | None = None  # (M, 3) grid points the NDF calls occupied
    heading_rad: float = float("nan")        # the handle's azimuth about up (ndfa.ndf.heading)
    heading_strength: float = 0.0            # how sure the NDF is of it
    category: str = UNKNOWN_CATEGORY         # the NDF's likeliest category ("unknown": a model without categories)
    category_probability: float = float("nan")  # and its probability
    # a skipped one that is a sighting (too small to encode, `ObservationConfig.sighting_pixels`):
    # its points' centroid, world; the detector counts it toward the object it falls on
    sighting_world: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True)
class AssociationEvent:
    """The intra-session update of one measurement (paper Sec. IV-A)."""

    session: Session
    frame_index: int
    instance_id: int
    object_id: int
    created: bool
    replaced: bool
    distance_m: float
    similarity: float
    candidates: int
    center_world: np.ndarray                 # the object's center after the update
    shape_code: np.ndarray                   # the object's code after the update
    category: str = UNKNOWN_CATEGORY         # the object's category after the update


@dataclass(frozen=True, kw_only=True)
class TreeEvent:
    """The session's object tree after a frame that changed it: nodes per axis and occupied cells."""

    session: Session
    frame_index: int
    x_intervals: np.ndarray                  # (Nx, 2) low, high
    y_intervals: np.ndarray                  # (Ny, 2)
    cells: list[tuple[int, int, tuple[int, ...]]] = field(default_factory=list)  # (x node, y node, object ids)
    # With the height tree T_z (`ndfa.change.config.LevelsConfig`): its nodes (Nz, 2) and each
    # node's object ids; a cell is then a column cell's objects in one T_z node. Empty: no T_z.
    z_intervals: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    z_objects: list[tuple[int, ...]] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class RegistrationEvent:
    """A registration attempt (paper Sec. IV-B): T_rel maps target-world points into the source world."""

    frame_index: int
    accepted: bool
    n_pairs: int
    n_hypotheses: int
    transform: np.ndarray | None             # (4, 4)
    inlier_pairs: tuple[tuple[int, int], ...]  # (target object, source object)
    residual_m: float
    target_centers: np.ndarray               # (K, 3) inlier target centers, target world
    source_centers: np.ndarray               # (K, 3) their source partners, source world
    method: RegistrationMethod = "object pairs"
    evidence: str = ""                       # "... (own evidence)": the figures it was accepted on


@dataclass(frozen=True, kw_only=True)
class GraphEvent:
    """One comparison of target object O with a shape-matched source object o' (paper Fig. 5)."""

    frame_index: int
    target_id: int
    source_id: int
    similarity: float
    mode: GraphMode                          # "graph", "in place" or "fallback" (ndfa.change.graph)
    consistent: bool
    distance_m: float
    center_source: np.ndarray                # T_rel t_O, source world
    partner_center_source: np.ndarray        # t_o'
    edges: tuple[tuple[int, int, float, bool], ...]  # (target neighbour, source neighbour, error m, consistent)
    target_edges_source: np.ndarray          # (E, 3) R e_Oj, source-world vectors
    source_edges: np.ndarray                 # (E, 3) e_o'j'


@dataclass(frozen=True, kw_only=True)
class DecisionEvent:
    """A change test of a target object, or a removal decided at the end.

    kind: "unchanged", "added" (changed in the target: new here), "removed" (a source object observed
    but never matched), "moved" (a changed target object that matches a removed source object by
    shape; assigned at the end) or "rotated" (an unchanged object whose handle turned about up by
    `angle_deg`; assigned at the end, `ndfa.change.rotation`). A change is reported the first time
    it is found and never retracted. A change whose place the other session did not show (an
    "added" object's place never shown well by the source, a removed one's by the target) is
    decided with `withheld` set, and not reported.

    score: how strongly the evidence says "changed", in [0, 1]; reported changes score at least
    `CHANGE_SCORE` and "unchanged" decisions below it, so thresholding the scores at another value
    trades precision against recall (`ndfa.change.verdict.decision_score`; docs/scores.md).
    NaN for decisions made without a score.
    """

    frame_index: int
    session: Session                         # whose object: "target" (added/moved/unchanged) or "source" (removed)
    object_id: int
    kind: DecisionKind
    reason: str
    center_world: np.ndarray                 # in that session's world frame
    center_source: np.ndarray | None         # in the source world (target objects: via T_rel)
    partner_id: int | None = None            # the source object it matched or moved from
    instance_ids: tuple[int, ...] = ()       # mask ids of the object's measurements
    partner_instance_ids: tuple[int, ...] = ()  # a move's source object's mask ids (it is reported with it)
    score: float = float("nan")
    angle_deg: float | None = None           # "rotated": the turn about up, degrees (source world, source -> target)
    category: str = UNKNOWN_CATEGORY         # the object's category (`SessionObject.category`)
    # Why the change is withheld, not reported: the other session's frames did not show its place
    # well enough to have found the object there (`ndfa.change.sight`); None: reported
    withheld: str | None = None
    sightings: int = 0                       # the object's sightings (`ndfa.change.sightings`) when decided

    @property
    def reported_instances(self) -> tuple[int, ...]:
        """The mask ids this report stands for (for scoring): the object's first, and for a move
        also the source object's first."""
        ids = self.instance_ids[:1] + self.partner_instance_ids[:1]
        return tuple(dict.fromkeys(ids))


@dataclass(frozen=True, kw_only=True)
class TimingEvent:
    """Wall time of each stage for one frame, milliseconds."""

    session: Session
    frame_index: int
    stage_ms: dict[str, float]


@dataclass(frozen=True, kw_only=True)
class PoseQualityEvent:
    """A session's estimated poses judged without ground truth, before its pass (the run emits it,
    not the pipeline: `ndfa.trajectory.quality`). verdict: "good", "doubtful" or "unusable";
    error_cm: the estimated error (NaN: nothing to estimate it from); text: the one-line summary;
    figures: the evidence by name."""

    session: str
    verdict: str
    error_cm: float
    text: str
    figures: dict[str, float | int | None] = field(default_factory=dict)


Event = (FrameEvent | ObservationEvent | AssociationEvent | TreeEvent | RegistrationEvent | GraphEvent | DecisionEvent
         | TimingEvent)
"""Every event the core returns and the sinks accept."""
