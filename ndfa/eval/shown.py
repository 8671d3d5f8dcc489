"""Which true changes two recordings could show at all: the places each session's frames showed.

The detector reports a change only where the other session showed its place well enough to have
found an object there (`ndfa.change.sight`). The scoring asks the same of the truth, so that a
change no detector could see is not counted as missed: a mug added where the source's camera only
passed 4 m away, or behind a monitor, may as well have stood there before; nothing in the
recordings tells. The scoring already leaves out a mug the target never showed (it cannot be
"added" to anyone) and a removed one the source never showed; this is the same rule for the other
session's view of the place. Here the place is judged with the true camera poses and the recorded
depth, over every frame (as the ground truth's `visible` is), by the detector's own bar: the rule's
object size (`EvidenceConfig.sight_*`) and perception's pixel minimum and depth range.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ndfa.change.config import EvidenceConfig
from ndfa.change.sight import SessionViews, SightRule
from ndfa.core.events import SESSIONS
from ndfa.io.recording import RecordingReader

OTHER = {"source": "target", "target": "source"}


def places_shown(readers: Mapping[str, RecordingReader], ground_truth: dict,
                 evidence: EvidenceConfig = EvidenceConfig(), rule: SightRule = SightRule()) -> dict[str, set[int]] | None:
    """Session -> the mugs whose place in that session the *other* session's frames showed (true
    poses); None when a recording has no true poses or the size rule is off."""
    if evidence.sight_radius_m <= 0 or not all(s in readers for s in SESSIONS):
        return None
    views = {}
    for session in SESSIONS:
        reader, seen = readers[session], SessionViews(rule)
        for frame in reader.frames():
            true = frame.pose_world_camera_true if frame.pose_world_camera_true is not None else \
                frame.pose_world_camera if reader.has_poses else None
            if true is None:
                return None
            seen.add(frame.index, frame.depth, frame.K, true)
        views[session] = seen
    shown: dict[str, set[int]] = {session: set() for session in SESSIONS}
    # The pose is the mug's base on its support: the place's center is half a mug above it, along the
    # up of a world the recording may hold tilted (a planted real recording's: `world_tilt`)
    tilt = ground_truth.get("world_tilt")
    up = np.asarray(tilt["pose_world_level"], dtype=float)[:3, 2] if tilt else np.array([0.0, 0.0, 1.0])
    for o in ground_truth.get("objects", []):
        for session in SESSIONS:
            if not o.get(session):
                continue
            place = np.asarray(o[session]["pose_world_object"], dtype=float)[:3, 3] + up * evidence.sight_height_m / 2
            if views[OTHER[session]].sight(place, evidence.sight_radius_m, evidence.sight_height_m).shown:
                shown[session].add(int(o["instance_id"]))
    return shown
