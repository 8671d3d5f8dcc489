"""`ndfa detect`'s score of a run on segmented frames (no masks): by position, in the true world.

A segmented object has no ground-truth instance id, so its report is named by the item standing at
its center (`ndfa.eval.position_match`). This module gathers what that needs from the run and the
recordings: the objects' final centers, the frames that saw each of them, each session's camera
poses as the run used them against the frames' true ones (for the maps into the true world: one
per reported object, fitted on the cameras that saw it, and one per session), and the visible
instances each recording's ground truth lists for its session.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ndfa.change.detector import ChangeDetector
from ndfa.core.events import DecisionEvent
from ndfa.eval.position_match import PositionScore, ReportedObject, align_worlds, score_by_position
from ndfa.eval.shown import places_shown
from ndfa.io.recording import RecordingReader
from ndfa.run.world import SessionWorld, spread

# Camera poses per session for the session-wide alignment, spread over the session: a rigid fit of
# 6 degrees of freedom is settled long before.
ALIGN_FRAMES = 100


def reported_object(maps: dict, cameras: dict, session: str, object_id: int, fallback: np.ndarray) -> ReportedObject:
    """`session`'s object `object_id` with its last center (as the objects table has it, not the one
    at decision time) and the map into the true world fitted on the cameras (`cameras[session][frame]`:
    run and true pose) of the frames that saw it; `fallback` when the map no longer holds it."""
    obj = maps[session].objects.get(object_id)
    if obj is None:
        return ReportedObject(session, object_id, fallback)
    seen = [cameras[session][f] for f in obj.frames if f in cameras[session]]
    local = align_worlds([run for run, _ in seen], [true for _, true in seen])[0] if seen else None
    return ReportedObject(session, object_id, obj.center_world, local)


def reports_of(changes: list[DecisionEvent], maps: dict, cameras: dict) -> list[list[ReportedObject]]:
    """Each change's reported objects: its own, and for a move the source object it left."""
    reports = []
    for change in changes:
        report = [reported_object(maps, cameras, change.session, change.object_id, change.center_world)]
        if change.kind == "moved" and change.partner_id is not None:
            report.append(reported_object(maps, cameras, "source", change.partner_id,
                                          maps["source"].objects[change.partner_id].center_world))
        reports.append(report)
    return reports


def score_segmented_run(changes: list[DecisionEvent], detector: ChangeDetector,
                        readers: dict[str, RecordingReader], worlds: dict[str, SessionWorld],
                        notes: list[str]) -> PositionScore | None:
    """The position score of `changes`, or None (a note says why) when a session's world cannot
    be aligned to the truth; appends a note on how it was scored."""
    maps = {"source": detector.source, "target": detector.target}
    named = [(c.session, c.object_id) for c in changes] + [
        ("source", c.partner_id) for c in changes if c.kind == "moved" and c.partner_id is not None]
    seen_in = {session: {f for s, i in named if s == session and i in maps[session].objects
                         for f in maps[session].objects[i].frames} for session in readers}
    pose_true_run, rmse, cameras = {}, {}, {}
    for session, reader in readers.items():
        # Among the frames with poses (those the run used, where it estimated poses on fewer: `ndfa.run.rate`).
        posed = worlds[session].posed
        sampled = spread(len(reader), ALIGN_FRAMES, posed)
        run_poses, true_poses, cameras[session] = [], [], {}
        # Every such frame is read (only poses are kept) when a reported object was seen in it.
        if posed is None:
            step = 1 if seen_in[session] else max(1, len(reader) // ALIGN_FRAMES)
            read: Sequence[int] = range(0, len(reader), step)
            frames = reader.frames(step=step)
        else:
            read = posed if seen_in[session] else sampled
            frames = reader.frames(positions=read)
        chosen = set(sampled)
        for position, frame in zip(read, frames):
            true = frame.pose_world_camera_true if frame.pose_world_camera_true is not None else \
                frame.pose_world_camera if reader.has_poses else None
            if true is None:
                notes.append(f"not scored: {reader.path} has no true camera poses (frame {frame.index}) to find "
                             "its objects in the ground truth's world")
                return None
            run = worlds[session].apply(frame).pose_world_camera
            if frame.index in seen_in[session]:
                cameras[session][frame.index] = (run, true)
            if position in chosen:
                run_poses.append(run)
                true_poses.append(true)
        pose_true_run[session], rmse[session] = align_worlds(run_poses, true_poses)

    reports = reports_of(changes, maps, cameras)
    truth = dict(readers["target"].ground_truth or {})
    # Each recording lists the sessions rendered up to it; the target's normally has both.
    visible: dict = {}
    for reader in readers.values():
        listed = (reader.ground_truth or {}).get("visible")
        visible |= listed if isinstance(listed, dict) else {}
    truth["visible"] = visible or None
    # The changes the recordings could show at all: the detector's own rule, with the true poses
    truth["shown"] = places_shown(readers, truth, detector.config.evidence, detector.views["source"].rule)
    result, _ = score_by_position(reports, truth, pose_true_run, rmse, kinds=[c.kind for c in changes])
    session_wide, _ = score_by_position([[replace(o, pose_true_run=None) for o in report] for report in reports],
                                        truth, pose_true_run, rmse, kinds=[c.kind for c in changes])
    result = replace(result, session_wide=(session_wide.tp, session_wide.fp, session_wide.fn))
    notes.append(result.describe())
    return result
