"""`ndfa detect`'s score of a run on segmented frames (no masks): by position, in the true world.

A segmented object has no ground-truth instance id, so its report is named by the item standing at
its center (`ndfa.eval.position_match`). This module gathers what that needs from the run and the
recordings: the objects' final centers, each session's camera poses as the run used them against
the frames' true ones (for the map into the true world), and the visible instances each
recording's ground truth lists for its session.
"""

from __future__ import annotations

import numpy as np

from ndfa.change.detector import ChangeDetector
from ndfa.core.events import DecisionEvent
from ndfa.eval.position_match import PositionScore, ReportedObject, align_worlds, score_by_position
from ndfa.io.recording import RecordingReader
from ndfa.run.world import SessionWorld

# Camera poses per session for the alignment, spread over the session: a rigid fit of 6 degrees of
# freedom is settled long before; reading every frame would decode every image again.
ALIGN_FRAMES = 100


def score_segmented_run(changes: list[DecisionEvent], detector: ChangeDetector,
                        readers: dict[str, RecordingReader], worlds: dict[str, SessionWorld],
                        notes: list[str]) -> PositionScore | None:
    """The position score of `changes`, or None (a note says why) when a session's world cannot
    be aligned to the truth; appends a note on how it was scored."""
    pose_true_run, rmse = {}, {}
    for session, reader in readers.items():
        run_poses, true_poses = [], []
        for frame in reader.frames(step=max(1, len(reader) // ALIGN_FRAMES)):
            true = frame.pose_world_camera_true if frame.pose_world_camera_true is not None else \
                frame.pose_world_camera if reader.has_poses else None
            if true is None:
                notes.append(f"not scored: {reader.path} has no true camera poses (frame {frame.index}) to find "
                             "its objects in the ground truth's world")
                return None
            run_poses.append(worlds[session].apply(frame).pose_world_camera)
            true_poses.append(true)
        pose_true_run[session], rmse[session] = align_worlds(run_poses, true_poses)

    maps = {"source": detector.source, "target": detector.target}

    def reported(session: str, object_id: int, fallback: np.ndarray) -> ReportedObject:
        # The object's last center (as the objects table has it), not the one at decision time.
        obj = maps[session].objects.get(object_id)
        return ReportedObject(session, object_id, fallback if obj is None else obj.center_world)

    reports = []
    for change in changes:
        report = [reported(change.session, change.object_id, change.center_world)]
        if change.kind == "moved" and change.partner_id is not None:
            partner = maps["source"].objects[change.partner_id]
            report.append(ReportedObject("source", change.partner_id, partner.center_world))
        reports.append(report)
    truth = dict(readers["target"].ground_truth or {})
    # Each recording lists the sessions rendered up to it; the target's normally has both.
    visible: dict = {}
    for reader in readers.values():
        listed = (reader.ground_truth or {}).get("visible")
        visible |= listed if isinstance(listed, dict) else {}
    truth["visible"] = visible or None
    result, _ = score_by_position(reports, truth, pose_true_run, rmse, kinds=[c.kind for c in changes])
    notes.append(result.describe())
    return result
