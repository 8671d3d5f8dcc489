"""How good a session's estimated poses are, without ground truth: figures, one estimated error in
centimetres, and one verdict (good / doubtful / unusable). docs/pose_quality.md has the
calibration against true errors and why the thresholds are where they are.

The evidence (`PoseEvidence`), gathered where the poses are estimated (`ndfa.trajectory.session`):

- the depth images' agreement under the estimated poses (`ndfa.trajectory.consistency`): at
  revisits (frames far apart along the path that look at the same place) and between neighbours;
- what the RGB-D odometry did: how far loop closure moved its keyframes, how well the loops agree
  after it, the share of frames that nothing pinned (a flat view without texture registered by
  depth alone, or a registration rejected and the motion guessed);
- the keyframes per frame (churn: the odometry losing its reference over and over).

Pure: frames' depth sketches, poses and the odometry's record in, figures out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from ndfa.trajectory.consistency import (
    ConsistencyConfig,
    DepthSketch,
    PairCheck,
    check_pairs,
    neighbour_pairs,
    revisit_pairs,
    step_pairs,
)
from ndfa.trajectory.rgbd_config import NO_TERM, POINT_TO_PLANE


@dataclass(frozen=True)
class PoseEvidence:
    """The no-truth figures of one session's poses (NaN where a figure has nothing to measure).

    frames, tracked: the session's frames and those with usable depth.
    revisit_pairs, neighbour_pairs: pairs of each kind that overlapped (each way counted).
    revisit_conflict_cm, neighbour_conflict_cm: the mean over the pairs of how deep the bulk (a
        quarter) of one frame's surfaces reach into the space the other saw empty, the larger of
        the pair's two ways (`PairCheck.shared_conflict_m`, `_shared_conflict_cm`): what a pose
        error does, and one surface disagreeing alone does not.
    revisit_local_conflict_cm: the mean over the revisits (each way) of the deepest 5 %
        (`PairCheck.conflict_m`): above the shared one where a few surfaces disagree alone (the
        office's screens, docs/pose_quality.md); judged only by `QualityThresholds.max_local_conflict_cm`.
    revisit_violation, neighbour_violation: share of the overlapping points seen through by the
        other frame (free-space violations; see `ndfa.trajectory.consistency`).
    step_conflict_cm: the largest conflict depth (deepest 5 %) between consecutive frames (a jump
        of the estimate).
    step_shared_conflict_cm: the largest shared conflict (`PairCheck.shared_conflict_m`, the bulk)
        between consecutive frames: what a step short of a jump counts in `judge`.
    jumps: consecutive frames whose conflict depth exceeds the consistency check's tau.
    unlinked: consecutive frames that hardly overlap under the estimate (below `min_overlap`):
        nothing in the images ties their poses together.
    keyframes, loops: the RGB-D odometry's keyframes and loop edges (0 for kiss-icp).
    graph_moved_cm: the largest distance loop closure moved a keyframe.
    loop_residual_cm: median distance between a loop edge's measured and optimised relative pose.
    unpinned_share: share of the tracked frames whose motion nothing pinned (see the module docstring).
    unseen_run: the longest run of consecutive frames whose registration kept the motion model's
        guess along a direction their depth could not see (a bare wall's slide and roll:
        `RgbdOdometry.unseen`); 0 for kiss-icp.
    backward_disagreement_cm: how far a second estimate, the same odometry over the frames in
        reverse order, lies from the poses (`session.estimate_session_poses` with `backward_frames`):
        its keyframes, and so its drift, are its own. The RMSE after SE(3) alignment with one break
        allowed (`metrics.one_break_error`): a stretch where one of the two lost its way (a jump,
        a slide along a bare wall) adds nothing, a drift along the path does. NaN when not run.
    """

    frames: int
    tracked: int
    revisit_pairs: int
    revisit_conflict_cm: float
    revisit_violation: float
    neighbour_pairs: int
    neighbour_conflict_cm: float
    neighbour_violation: float
    step_conflict_cm: float
    jumps: int
    unlinked: int
    keyframes: int
    loops: int
    graph_moved_cm: float
    loop_residual_cm: float
    unpinned_share: float
    unseen_run: int = 0
    backward_disagreement_cm: float = float("nan")
    revisit_local_conflict_cm: float = float("nan")
    step_shared_conflict_cm: float = float("nan")

    def to_dict(self) -> dict:
        return {key: (None if isinstance(value, float) and not np.isfinite(value) else value)
                for key, value in asdict(self).items()}


def gather_evidence(poses: Sequence[np.ndarray], sketches: dict[int, DepthSketch], odometry: object,
                    odometry_positions: Sequence[int], config: ConsistencyConfig = ConsistencyConfig()) -> PoseEvidence:
    """The evidence for a session: `poses` (every frame's, camera-to-world), `sketches` by position
    in the session (frames with usable depth), the odometry after `finish`, and the session
    positions of the frames it was fed, in its order."""
    positions = sorted(sketches)
    tracked_poses = np.array([poses[p] for p in positions]).reshape(-1, 4, 4)
    sketch_list = [sketches[p] for p in positions]
    revisits: list[PairCheck] = []
    neighbours: list[PairCheck] = []
    steps: list[PairCheck] = []
    if len(positions) >= 2:
        median_depths = np.array([sketch.median_depth_m for sketch in sketch_list])
        revisits = check_pairs(sketch_list, tracked_poses, revisit_pairs(tracked_poses, median_depths, config), config)
        neighbours = check_pairs(sketch_list, tracked_poses, neighbour_pairs(tracked_poses, config), config)
        # Both ways: a jump towards the surfaces in view shows one way, a jump away from them the other.
        steps = check_pairs(sketch_list, tracked_poses, step_pairs(len(positions)), config)
    unlinked = max(0, len(positions) - 1 - len({min(check.i, check.j) for check in steps}))
    keyframes, loops, moved, loop_residual, unpinned = _odometry_figures(poses, odometry, odometry_positions)
    return PoseEvidence(frames=len(poses), tracked=len(positions),
                        revisit_pairs=len(revisits), revisit_conflict_cm=_shared_conflict_cm(revisits),
                        revisit_local_conflict_cm=_conflict_cm(revisits),
                        revisit_violation=_violation(revisits), neighbour_pairs=len(neighbours),
                        neighbour_conflict_cm=_shared_conflict_cm(neighbours),
                        neighbour_violation=_violation(neighbours),
                        step_conflict_cm=100.0 * max((check.conflict_m for check in steps), default=float("nan")),
                        step_shared_conflict_cm=100.0 * max((check.shared_conflict_m for check in steps),
                                                            default=float("nan")),
                        jumps=len({min(check.i, check.j) for check in steps if check.conflict_m > config.tau_m}),
                        unlinked=unlinked,
                        keyframes=keyframes, loops=loops, graph_moved_cm=moved, loop_residual_cm=loop_residual,
                        unpinned_share=unpinned, unseen_run=_longest_run(getattr(odometry, "unseen", [])))


def _longest_run(flags: Sequence[bool]) -> int:
    longest = current = 0
    for flag in flags:
        current = current + 1 if flag else 0
        longest = max(longest, current)
    return longest


def _conflict_cm(checks: list[PairCheck]) -> float:
    return 100.0 * float(np.mean([check.conflict_m for check in checks])) if checks else float("nan")


def _shared_conflict_cm(checks: list[PairCheck]) -> float:
    """The mean over the pairs of the larger of a pair's two ways' shared conflict: a wrong relative
    pose shows one way (the surfaces of the frame set too near the other's camera), while the other
    way they stand behind, hidden."""
    pairs: dict[tuple[int, int], float] = {}
    for check in checks:
        key = (min(check.i, check.j), max(check.i, check.j))
        pairs[key] = max(pairs.get(key, 0.0), check.shared_conflict_m)
    return 100.0 * float(np.mean(list(pairs.values()))) if pairs else float("nan")


def _violation(checks: list[PairCheck]) -> float:
    overlap = sum(check.overlap for check in checks)
    return sum(check.violating for check in checks) / overlap if overlap else float("nan")


def _odometry_figures(poses: Sequence[np.ndarray], odometry: object,
                      odometry_positions: Sequence[int]) -> tuple[int, int, float, float, float]:
    """keyframes, loops, graph_moved_cm, loop_residual_cm, unpinned_share from an RgbdOdometry
    (duck-typed: kiss-icp's DepthOdometry has no keyframes, and gives its rejected refinements)."""
    keyframes = getattr(odometry, "keyframes", None)
    fed = max(1, len(odometry_positions))
    if not keyframes:
        rejected = getattr(odometry, "refinements_rejected", 0) + getattr(odometry, "starved_frames", 0)
        return 0, 0, float("nan"), float("nan"), rejected / fed
    terms, degenerate = list(odometry.terms), list(odometry.degenerate)  # type: ignore[attr-defined]
    guessed = sum(term == NO_TERM for term in terms[1:])
    slid = sum(flag and term == POINT_TO_PLANE for term, flag in zip(terms, degenerate, strict=True))
    unpinned = (guessed + slid + odometry.rejected_frames) / fed  # type: ignore[attr-defined]
    # Loop closure holds the first keyframe fixed, so the final pose of its frame is the anchor.
    final = [np.asarray(poses[odometry_positions[keyframe.frame]]) for keyframe in keyframes]
    anchor = final[0] @ np.linalg.inv(keyframes[0].pose)
    moved = max(float(np.linalg.norm(pose[:3, 3] - (anchor @ keyframe.pose)[:3, 3]))
                for pose, keyframe in zip(final, keyframes, strict=True))
    corrected = [np.linalg.inv(anchor) @ pose for pose in final]
    loop_edges = [edge for edge in odometry.edges if edge.loop]  # type: ignore[attr-defined]
    residuals = [float(np.linalg.norm((np.linalg.inv(edge.target_from_source) @ np.linalg.inv(corrected[edge.target])
                                       @ corrected[edge.source])[:3, 3])) for edge in loop_edges]
    loop_residual = 100.0 * float(np.median(residuals)) if residuals else float("nan")
    return len(keyframes), len(loop_edges), 100.0 * moved, loop_residual, unpinned


GOOD, DOUBTFUL, UNUSABLE = "good", "doubtful", "unusable"
VERDICTS = (GOOD, DOUBTFUL, UNUSABLE)


@dataclass(frozen=True)
class QualityThresholds:
    """Where the estimated error turns the verdict (docs/pose_quality.md: the calibration).

    doubtful_cm, unusable_cm: the estimated error (`PoseQuality.error_cm`) above which the poses
        are doubtful, unusable. Right poses give 0-1 cm on the simulator's sessions and 5-6 cm on
        the 7-Scenes kitchen (a Kinect's depth noise and edges); drifted or broken ones 29 cm and up.
    min_pairs: fewer revisit pairs than this say too little: the revisits are left out.
    max_unseen_run: a run of this many consecutive frames whose motion the odometry partly guessed
        (`PoseEvidence.unseen_run`: a bare wall in view) makes the poses doubtful at best: what
        happened along the wall is not in the images, and the conflict depths cannot see a slide
        along the only surface in view.
    backward_factor: the estimated error is at least this many times the backward estimate's
        disagreement (`PoseEvidence.backward_disagreement_cm`). The two share what the images get
        wrong the same way either way (the simulator's sessions: a scale error, so the true error is
        several times the disagreement), and less on the 7-Scenes kitchen, which stays good at 2
        (docs/pose_quality.md: the calibration).
    max_local_conflict_cm: revisits whose deepest 5 % reach this deep on average
        (`PoseEvidence.revisit_local_conflict_cm`) make the poses doubtful at best: some surfaces
        stand decimetres into space seen empty, a doubled wall where a drift stayed local (the
        paper's raw source without loop closure: 35.7 cm at ATE 6.4 cm, its shared conflict 0.2 cm)
        or many screens' reflections (the right office sessions: up to 8.4 cm).
    """

    doubtful_cm: float = 10.0
    unusable_cm: float = 25.0
    min_pairs: int = 10
    max_unseen_run: int = 5
    backward_factor: float = 2.0
    max_local_conflict_cm: float = 25.0
    # Good poses hold the session's horizontal planes level in every frame: fewer than this share
    # of the up estimate's frames whose own plane lies within its `agree_deg` (5 deg) of up makes
    # them doubtful at best (`up_disagreement`). The frames tilt against each other, a rotation
    # drift the conflict depths can miss where the drifted frames never meet again: a 30 Hz walk
    # tracked frame by frame, 20-37 cm off, judged good at 1.3 cm, 12 and 34 of 62 frames
    # agreeing; 0.95-1.0 on every right session of the validation sets (docs/pose_quality.md).
    min_up_agreement: float = 0.8


@dataclass(frozen=True)
class PoseQuality:
    """A session's poses judged without ground truth: `error_cm`, the estimated error (how deep the
    frames' surfaces reach into space other frames saw empty, see `judge`), the `verdict`, and
    `basis`, what the error rests on."""

    evidence: PoseEvidence
    error_cm: float
    verdict: str
    basis: str  # "revisits and neighbours", "neighbours" or "none"
    doubt: str = ""  # evidence beyond the depths that made the verdict worse (`up_disagreement`)

    @property
    def good(self) -> bool:
        return self.verdict == GOOD

    def describe(self) -> str:
        """One line: the verdict, the estimated error and what it rests on."""
        e = self.evidence
        if self.basis == "none":
            figure = "no overlapping frames to check the poses by"
        elif e.loops and self.error_cm == e.loop_residual_cm:
            figure = (f"estimated error {self.error_cm:.1f} cm: the loop closures lie that far from the optimised "
                      f"poses (median), the loops and the odometry disagree")
        else:
            figure = (f"estimated error {self.error_cm:.1f} cm: surfaces of one frame up to that deep in space another "
                      f"saw empty, at {e.revisit_pairs} revisits and {e.neighbour_pairs} neighbour pairs")
        if e.jumps:
            figure += f"; {e.jumps} jump(s) between consecutive frames (up to {e.step_conflict_cm:.0f} cm)"
        if e.unlinked:
            figure += f"; {e.unlinked} consecutive frame pair(s) with no overlap: nothing ties their poses"
        if e.revisit_local_conflict_cm > QualityThresholds.max_local_conflict_cm:
            figure += (f"; surfaces up to {e.revisit_local_conflict_cm:.0f} cm deep in space seen empty on part of the "
                       "revisits' overlap (a doubled surface, or reflections)")
        if e.unseen_run:
            figure += (f"; {e.unseen_run} consecutive frame(s) whose depth saw only part of their motion (a bare "
                       "wall?), the rest guessed")
        loops = f"; {e.loops} loop closures, moving keyframes up to {e.graph_moved_cm:.0f} cm" if e.loops else ""
        doubt = f"; {self.doubt}" if self.doubt else ""
        return f"pose quality {self.verdict.upper()} ({figure}{loops}{doubt})"

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "basis": self.basis,
                "estimated_error_cm": round(self.error_cm, 2) if np.isfinite(self.error_cm) else None,
                "figures": self.evidence.to_dict()} | ({"doubt": self.doubt} if self.doubt else {})


def up_disagreement(quality: PoseQuality, agreeing: int, frames: int,
                    thresholds: QualityThresholds = QualityThresholds()) -> PoseQuality:
    """`quality`, doubtful at best where fewer than `min_up_agreement` of the `frames` the up was
    estimated from (`UpEstimate.frames_used`) agree on it (`frames_agreeing`): the poses tilt the
    frames' horizontal planes against each other."""
    if quality.verdict != GOOD or frames == 0 or agreeing >= thresholds.min_up_agreement * frames:
        return quality
    return replace(quality, verdict=DOUBTFUL, doubt=(
        f"only {agreeing} of {frames} frames' own horizontal planes agree on up: the poses tilt the frames against "
        "each other (rotation drift?)"))


def judge(evidence: PoseEvidence, thresholds: QualityThresholds = QualityThresholds()) -> PoseQuality:
    """The estimated error and the verdict. The error is the largest of the conflict depths: at the
    revisits (drift shows there; with at least `min_pairs` of them) and between neighbours (a broken
    registration), each the depth a quarter of a pair's overlap reaches (a pose error moves every
    surface, a reflection one), and the largest between consecutive frames (a jump, beyond the
    consistency check's tau: its deepest 5 %; short of one, the bulk as above), the loop closures' median residual after the graph's optimisation (loops and odometry that
    disagree), and, when it was run, the backward estimate's disagreement times `backward_factor`
    (smooth drift). Consecutive frames that do not overlap leave the poses on either side unrelated,
    and a run of frames whose motion was partly guessed (`max_unseen_run`) leaves them unmeasured,
    and revisits whose deepest 5 % conflict deeply (`max_local_conflict_cm`) show a doubled surface:
    at best doubtful. With no pair to check, nothing contradicts the poses and nothing vouches for
    them: doubtful."""
    # A jump (deepest 5 % beyond tau) counts at its depth; short of that, a step counts as the
    # revisits and neighbours do, by its bulk: one 2 cm slip that the path absorbs is not its error.
    step = evidence.step_conflict_cm
    if not evidence.jumps and np.isfinite(evidence.step_shared_conflict_cm):
        step = evidence.step_shared_conflict_cm
    figures = [evidence.neighbour_conflict_cm, step]
    basis = "neighbours"
    if evidence.revisit_pairs >= thresholds.min_pairs:
        figures.append(evidence.revisit_conflict_cm)
        basis = "revisits and neighbours"
    figures = [figure for figure in figures if np.isfinite(figure)]
    if not figures:
        return PoseQuality(evidence, float("nan"), DOUBTFUL, "none")
    # Loops the optimised graph leaves far from what they measured: the loops and the odometry
    # disagree, so one of them is wrong (right sessions: under 0.5 cm).
    error = max(figures + [evidence.loop_residual_cm] * bool(np.isfinite(evidence.loop_residual_cm)))
    if np.isfinite(evidence.backward_disagreement_cm):  # drift: what the conflict depths cannot see
        error = max(error, thresholds.backward_factor * evidence.backward_disagreement_cm)
    verdict = UNUSABLE if error > thresholds.unusable_cm else DOUBTFUL if error > thresholds.doubtful_cm else GOOD
    local = evidence.revisit_pairs >= thresholds.min_pairs and evidence.revisit_local_conflict_cm > thresholds.max_local_conflict_cm
    if (evidence.unlinked or evidence.unseen_run >= thresholds.max_unseen_run or local) and verdict == GOOD:
        verdict = DOUBTFUL
    return PoseQuality(evidence, error, verdict, basis)


def _zero_nan(value: float) -> float:
    return value if np.isfinite(value) else 0.0
