"""Scoring a run without masks (segmented frames) by position: which ground-truth item each report is.

With masks, a reported object carries the instance id of the mask that made it (`ndfa.eval.scoring`).
Segmented frames give it only a segment label, so here each reported object is named by where it
is: its center is matched to the nearest ground-truth item of its session (a mug placed in that
session, or a clutter item) within `MATCH_RADIUS_M` horizontally, and the matched ids are scored as
a masked run's are. A report on clutter, or on nothing, is a false positive of its own (clutter is
never a change; an object where nothing stands is a phantom).

Positions are compared in the true world. A run's world is not the truth's: poses estimated by
odometry start from the first camera, a levelled world is turned, and even `--poses truth` is
levelled when the recording's world is tilted. So the map to the true world comes from the
cameras: the rigid fit (`kabsch`, as the ATE's alignment in `ndfa.trajectory.metrics`) of the
run's camera poses onto the frames' true ones, positions and orientations both (a point a fixed
distance along each camera axis, so that a route that is nearly a straight line still fixes the
rotation about it). Each reported object is mapped by the fit of the cameras of the frames that
saw it (`ReportedObject.pose_true_run`; `ndfa.eval.position_score`): the odometry's drift moves an
object by the error of the poses it was measured from, not by the session's average error, and a
fit of the whole session leaves that drift (4.5-6 cm on the kitchen halves) in the distance to the
item, which the radius is not made for. Where every pose is exact up to one rigid motion (given
poses, a levelled world) the two fits are the same motion. The session's fit (`align_worlds` over
all its cameras) maps an object the frames of which are unknown; its residual is reported with the
score: the drift a session-wide map would have left (docs/plant.md, "Scoring under drift").

Which mugs a session shows comes from the ground truth's `visible` (the simulator counts its masks
while rendering, by `is_visible`): without it, every mug is scored.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.geometry import invert_pose, kabsch
from ndfa.eval.scoring import KindReport, Score, score

# About a mug's footprint radius (handle included): a report counts as an item when its center lies
# on the item's footprint, with room for the center's error (the mean of the points seen, a few cm
# off the axis when one side was seen, plus what the alignment leaves). Items stand apart by their
# footprints plus a clearance (`ndfa.sim.world`; no two of one session nearer than 11.6 cm on the
# seven scenes of issue 16), so an object standing elsewhere is not credited to an item, and the
# nearest item wins where two are within reach. Horizontal: a center's height depends on how much
# of the object the views saw (a rim seen from above sits high), not on which object it is; only
# between items within reach stacked on shelves it tells the level: an object's center lies between
# `LEVEL_BELOW_M` under its base and `LEVEL_ABOVE_M` over it (up to 36 cm tall, its center a few cm
# off), short of a board 25 cm away.
MATCH_RADIUS_M = 0.07
LEVEL_BELOW_M, LEVEL_ABOVE_M = 0.05, 0.25
# The camera axes' points for the alignment lie this far from the camera: about the scale of the
# room's distances, so that positions and orientations weigh alike in the fit.
AXIS_POINT_M = 1.0


@dataclass(frozen=True)
class ReportedObject:
    """One object a report names: a change's object, or a move's source object."""

    session: str
    object_id: int
    center_world: np.ndarray  # (3,) in the run's world of that session
    # (4, 4) the run's world -> the true world where this object was seen (the fit of the cameras of
    # the frames that saw it); None: the session's (`score_by_position`'s `pose_true_run`)
    pose_true_run: np.ndarray | None = None


@dataclass(frozen=True)
class Match:
    """The ground-truth item a reported object stands for."""

    reported: ReportedObject
    instance_id: int | None  # None: nothing within the radius
    kind: str                # "mug", "clutter:<kind>" or "nothing"
    distance_m: float        # horizontal, to the matched item (or to the nearest one when nothing)
    nearest: str = ""        # for "nothing": the nearest item, e.g. "mug 3"

    def describe(self) -> str:
        o = self.reported
        if self.instance_id is None:
            return f"{o.session} object {o.object_id} (nearest {self.nearest or 'item: none'} at {self.distance_m:.2f} m)"
        return f"{o.session} object {o.object_id} = {self.kind} {self.instance_id}"


@dataclass(frozen=True)
class PositionScore(Score):
    """A `Score` whose instance ids were found by position; clutter and unmatched reports are FPs."""

    clutter_ids: tuple[int, ...] = ()     # clutter items reported as changes
    unmatched: tuple[str, ...] = ()       # reported objects where no item stands (described)
    alignment_rmse_m: dict[str, float] = field(default_factory=dict)  # per session, camera positions
    local_alignment: bool = False  # each reported object mapped by the cameras that saw it
    # (TP, FP, FN) with every object mapped by its session's alignment instead: what drift costs a
    # session-wide map (docs/plant.md, "Scoring under drift"); None when not computed
    session_wide: tuple[int, int, int] | None = None
    visibility_known: bool = True
    radius_m: float = MATCH_RADIUS_M

    def as_dict(self) -> dict:
        return super().as_dict() | {"scored_by": "position", "radius_m": self.radius_m,
                                    "fp_ids": list(self.false_positive_ids), "fn_ids": list(self.false_negative_ids),
                                    "clutter_fp": list(self.clutter_ids), "unmatched_fp": list(self.unmatched),
                                    "alignment_rmse_m": dict(self.alignment_rmse_m),
                                    "alignment": "per object" if self.local_alignment else "per session",
                                    "session_wide": None if self.session_wide is None else dict(
                                        zip(("tp", "fp", "fn"), self.session_wide)),
                                    "visibility_known": self.visibility_known}

    def describe(self) -> str:
        """One line for the notes: how it was scored and what the FPs beyond the mugs were."""
        rmse = ", ".join(f"{s} {v:.3f} m" for s, v in self.alignment_rmse_m.items())
        aligned = "each object by the cameras that saw it" if self.local_alignment else "by its cameras"
        line = (f"scored by position: each reported object is the ground-truth item nearest its center within "
                f"{self.radius_m * 100:.0f} cm horizontally, in the true world (run world aligned {aligned}; "
                f"camera RMSE after a session-wide alignment: {rmse})")
        if self.session_wide is not None:
            line += "; aligned per session instead: TP {} / FP {} / FN {}".format(*self.session_wide)
        if not self.visibility_known:
            line += "; the ground truth lists no visible instances, so every mug is scored"
        if self.clutter_ids:
            line += f"; FP on clutter: {', '.join(map(str, self.clutter_ids))}"
        if self.unmatched:
            line += f"; FP on nothing: {'; '.join(self.unmatched)}"
        return line


def alignment_points(poses: np.ndarray) -> np.ndarray:
    """(4N, 3): each camera's position and a point `AXIS_POINT_M` along each of its axes."""
    poses = np.asarray(poses, dtype=np.float64)
    positions = poses[:, :3, 3]
    axes = positions[:, None, :] + AXIS_POINT_M * np.swapaxes(poses[:, :3, :3], 1, 2)  # rows: x, y, z axes
    return np.concatenate([positions[:, None, :], axes], axis=1).reshape(-1, 3)


def align_worlds(run_poses: Sequence[np.ndarray] | np.ndarray,
                 true_poses: Sequence[np.ndarray] | np.ndarray) -> tuple[np.ndarray, float]:
    """pose_true_run (4, 4): the rigid motion that best maps the run's camera poses onto the true
    ones of the same frames (positions and orientations); and the RMSE of the camera positions
    after it, metres."""
    run_poses, true_poses = np.asarray(run_poses, dtype=np.float64), np.asarray(true_poses, dtype=np.float64)
    if run_poses.shape != true_poses.shape or run_poses.ndim != 3 or run_poses.shape[1:] != (4, 4) or len(run_poses) < 1:
        raise ValueError(f"need two (N, 4, 4) pose arrays of the same frames, got {run_poses.shape} and {true_poses.shape}")
    pose_true_run, _ = kabsch(alignment_points(run_poses), alignment_points(true_poses))
    moved = run_poses[:, :3, 3] @ pose_true_run[:3, :3].T + pose_true_run[:3, 3]
    rmse = float(np.sqrt(np.mean(np.sum((moved - true_poses[:, :3, 3]) ** 2, axis=1))))
    return pose_true_run, rmse


def truth_items(ground_truth: dict, session: str) -> list[tuple[int, str, np.ndarray]]:
    """(instance id, kind, base (3,): where it stands, in the true level world) of every item
    standing in `session`: its mugs and the (static) clutter."""
    level_world = _level_world(ground_truth)
    items = []
    for o in ground_truth.get("objects", []):
        if o.get(session):
            items.append((int(o["instance_id"]), "mug", _levelled(level_world, np.array(o[session]["pose_world_object"])[:3, 3])))
    for c in ground_truth.get("clutter", []):
        items.append((int(c["instance_id"]), f"clutter:{c['kind']}",
                      _levelled(level_world, np.array(c["pose_world_object"])[:3, 3])))
    return items


def match_object(reported: ReportedObject, ground_truth: dict, pose_true_run: np.ndarray,
                 radius_m: float = MATCH_RADIUS_M) -> Match:
    """The item of the report's session nearest its center (true world, horizontally) within
    `radius_m`, of those the center stands on the level of if any (`LEVEL_BELOW_M`,
    `LEVEL_ABOVE_M`: items stacked on shelves); the center mapped by the report's own
    `pose_true_run` when it has one, else by `pose_true_run`."""
    if reported.pose_true_run is not None:
        pose_true_run = reported.pose_true_run
    center_true = pose_true_run[:3, :3] @ np.asarray(reported.center_world, dtype=np.float64) + pose_true_run[:3, 3]
    center = _levelled(_level_world(ground_truth), center_true)
    items = truth_items(ground_truth, reported.session)
    if not items:
        return Match(reported, None, "nothing", float("inf"))
    distances = [float(np.linalg.norm(base[:2] - center[:2])) for _, _, base in items]
    within = [k for k, distance in enumerate(distances) if distance <= radius_m]
    on_level = [k for k in within if -LEVEL_BELOW_M <= center[2] - items[k][2][2] <= LEVEL_ABOVE_M]
    best = min(on_level or within or range(len(items)), key=lambda k: distances[k])
    instance_id, kind, _ = items[best]
    if distances[best] <= radius_m:
        return Match(reported, instance_id, kind, distances[best])
    return Match(reported, None, "nothing", distances[best], nearest=f"{kind} {instance_id}")


def score_by_position(reports: Sequence[Sequence[ReportedObject]], ground_truth: dict,
                      pose_true_run: Mapping[str, np.ndarray], alignment_rmse_m: Mapping[str, float] | None = None,
                      radius_m: float = MATCH_RADIUS_M, kinds: Sequence[str] = ()) -> tuple[PositionScore, list[Match]]:
    """Score reports (each: the objects it names) by the items at their centers; `pose_true_run`
    maps each session's run world to the true world (`align_worlds`) where a reported object brings
    no map of its own (`ReportedObject.pose_true_run`). Mugs are scored by
    `ndfa.eval.scoring.score` with the ground truth's visibility; every distinct clutter item
    reported and every reported object matched to nothing add one FP. `kinds`: each report's
    kind, for the per-kind score (a report whose first object is no mug has none)."""
    per_report = [[match_object(o, ground_truth, pose_true_run[o.session], radius_m) for o in report]
                  for report in reports]
    matches = [m for report in per_report for m in report]
    said = [KindReport(kind, report[0].instance_id, report[1].instance_id if len(report) > 1 else None)
            for kind, report in zip(kinds, per_report)
            if report and report[0].kind == "mug" and report[0].instance_id is not None]
    mug_ids = [m.instance_id for m in matches if m.kind == "mug" and m.instance_id is not None]
    clutter = tuple(sorted({m.instance_id for m in matches if m.kind.startswith("clutter") and m.instance_id is not None}))
    # Object level, as for mugs: an object named by two reports is one FP.
    unmatched = tuple(dict.fromkeys(m.describe() for m in matches if m.instance_id is None))
    listed = ground_truth.get("visible")
    visible = {s: {int(i) for i in ids} for s, ids in listed.items()} if isinstance(listed, dict) else None
    if visible is not None and not {"source", "target"} <= visible.keys():
        visible = None  # one session's list is no list: scoring the other's mugs as invisible would be wrong
    listed_shown = ground_truth.get("shown")
    shown = {s: {int(i) for i in ids} for s, ids in listed_shown.items()} if isinstance(listed_shown, dict) else None
    mugs = score(mug_ids, ground_truth, visible, kinds=said, shown=shown)
    # Unmatched objects have no id: negative ones of their own, so that each is one FP.
    extra = clutter + tuple(-(k + 1) for k in range(len(unmatched)))
    result = PositionScore(
        mugs.tp, mugs.fp + len(extra), mugs.fn, mugs.true_positive_ids, mugs.false_positive_ids + extra,
        mugs.false_negative_ids, mugs.unscored_ids, clutter_ids=clutter, unmatched=unmatched,
        kinds=mugs.kinds, kinds_found=mugs.kinds_found, categories=mugs.categories, unshown_ids=mugs.unshown_ids,
        alignment_rmse_m=dict(alignment_rmse_m or {}),
        visibility_known=visible is not None, radius_m=radius_m,
        local_alignment=any(o.pose_true_run is not None for report in reports for o in report))
    return result, matches


def _level_world(ground_truth: dict) -> np.ndarray:
    """pose_level_world: the true world levelled (the identity unless the simulator tilted it)."""
    tilt = ground_truth.get("world_tilt")
    return np.eye(4) if not tilt else invert_pose(np.array(tilt["pose_world_level"], dtype=np.float64))


def _levelled(pose_level_world: np.ndarray, point_world: np.ndarray) -> np.ndarray:
    return pose_level_world[:3, :3] @ point_world + pose_level_world[:3, 3]
