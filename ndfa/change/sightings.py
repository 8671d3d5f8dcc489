"""Sightings: views of an object too small to encode, counted as evidence that the object exists.

Perception encodes a view only from `ObservationConfig.min_pixels`; a smaller one, from
`sighting_pixels`, still says where something stood (its cleaned points' centroid: a `Sighting`,
no shape code). The waiting policy tests an object only from `WaitingConfig.min_measurements`
views because an object's first views are often fragments; an object measured once but sighted in
many frames around it is no fragment. So each session counts the sightings that fall on each of
its objects, and with `WaitingConfig.sightings` they count toward the minimum (its first
measurement still a real one: shape codes and centers come only from measurements).

A sighting falls on the nearest (in 3D) object of the session's map whose center is within `reach_m`
horizontally (`EvidenceConfig.sight_radius_m`, the large mug's radius: a view's centroid lies
on the object's camera-facing surface, at most a radius off its axis, plus
`AssociationConfig.distance_m`, the association's own allowance for one object's centers) and
`EvidenceConfig.sight_height_m` in height, and was not measured in the sighting's frame (one
frame's masks are different objects). Online an object's sightings often come before it is first
measured (it is approached from afar), so a sighting that falls on no object is kept, the latest
`KEEP` of them per session, and claimed when an object is measured within reach of it.

The same evidence stands against a change: where a session sighted something in at least
`WaitingConfig.min_measurements` frames and its map holds no object there to be it, it did not see
the place empty, and an "added" (the source's sightings) or "removed" (the target's) object there
is withheld (`unexplained`; the detector's place test, `ndfa.change.detector`). Every sighting that
fell on no object is kept for it, its point exact: a count that binned points in cells would depend
on where the world's origin lies, and a few centimetres of world frame (a bag round trip's estimated
up) would move a place's count across the bar. `MAX_UNCLAIMED` bounds them.

Pure numpy; no I/O. Why and what it changes: docs/detector.md, "Sightings".
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ndfa.change.associate import SessionMap
from ndfa.change.config import DetectorConfig
from ndfa.core.conventions import UP_AXIS, horizontal
from ndfa.core.events import ObservationEvent

# The unclaimed sightings a session keeps (the latest): a few seconds of frames with a few small
# masks each, so that an object approached from afar claims its early sightings when first measured.
KEEP = 256
# The sightings that fell on no object kept for `unexplained`, the latest: a few small masks a frame
# over tens of thousands of frames (a few MB at most), so memory stays flat in a recording's length.
MAX_UNCLAIMED = 100_000


@dataclass(frozen=True)
class Sighting:
    """A view of something too small to encode, in the session's world frame."""

    frame_index: int
    instance_id: int          # the mask's id (kept for analysis; the method does not use it)
    center_world: np.ndarray  # (3,) its cleaned points' centroid
    n_pixels: int

    @classmethod
    def of(cls, observation: ObservationEvent) -> Sighting | None:
        """The sighting of a skipped observation; None when it is none."""
        if observation.sighting_world is None:
            return None
        return cls(observation.frame_index, observation.instance_id, observation.sighting_world, observation.n_pixels)


class SessionSightings:
    """One session's sightings: how many fell on each object, and the latest that fell on none."""

    def __init__(self, config: DetectorConfig) -> None:
        evidence = config.evidence
        self.reach_m = evidence.sight_radius_m + config.association.distance_m
        self.height_m = evidence.sight_height_m
        self.counts: dict[int, int] = {}
        self.loose: deque[tuple[int, Sighting]] = deque(maxlen=KEEP)  # (its key in `unclaimed`, it)
        self.unclaimed: dict[int, np.ndarray] = {}  # the points of the sightings that fell on no object
        self._kept = 0  # sightings kept so far: the next key

    def count(self, object_id: int) -> int:
        return self.counts.get(object_id, 0)

    def add(self, sightings: list[Sighting], session_map: SessionMap) -> None:
        """A frame's sightings, after its measurements joined `session_map`: each counts for the
        object it falls on, or is kept until one is measured there."""
        for sighting in sightings:
            object_id = self._falls_on(sighting, session_map, list(session_map.objects))
            if object_id is None:
                self._keep(sighting)
            else:
                self.counts[object_id] = self.count(object_id) + 1

    def unexplained(self, place: np.ndarray, session_map: SessionMap) -> int:
        """How many sightings that fell on no object lie within reach of `place` (horizontally and
        in height, as a sighting falls on an object), none of the map's objects within reach of them."""
        if not self.unclaimed:
            return 0
        points = np.array(list(self.unclaimed.values()))
        points = points[self._within(points - place)]
        if len(points) and session_map.objects:
            centers = np.array([o.center_world for o in session_map.objects.values()])
            points = points[~self._within(points[:, None, :] - centers[None]).any(axis=1)]
        return len(points)

    def _within(self, offsets: np.ndarray) -> np.ndarray:
        within: np.ndarray = ((np.linalg.norm(horizontal(offsets), axis=-1) <= self.reach_m)
                              & (np.abs(offsets[..., UP_AXIS]) <= self.height_m))
        return within

    def _keep(self, sighting: Sighting) -> None:
        """A sighting that fell on no object: kept to be claimed, and counted by `unexplained`."""
        self.loose.append((self._kept, sighting))
        self.unclaimed[self._kept] = np.asarray(sighting.center_world, dtype=float)
        self._kept += 1
        if len(self.unclaimed) > MAX_UNCLAIMED:
            del self.unclaimed[next(iter(self.unclaimed))]

    def claim(self, object_ids: list[int], session_map: SessionMap) -> None:
        """The kept sightings that fall on one of `object_ids` (just measured) now count for it."""
        if not self.loose or not object_ids:
            return
        kept: deque[tuple[int, Sighting]] = deque(maxlen=KEEP)
        for key, sighting in self.loose:
            object_id = self._falls_on(sighting, session_map, object_ids)
            if object_id is None:
                kept.append((key, sighting))
            else:
                self.counts[object_id] = self.count(object_id) + 1
                self.unclaimed.pop(key, None)
        self.loose = kept

    def _falls_on(self, sighting: Sighting, session_map: SessionMap, object_ids: list[int]) -> int | None:
        """The nearest of `object_ids` the sighting falls on (see the module), or None."""
        objects = [o for o in (session_map.objects[i] for i in object_ids)
                   if sighting.frame_index != o.last_frame and sighting.frame_index not in o.frames]
        if not objects:
            return None
        offsets = np.array([o.center_world for o in objects]) - sighting.center_world
        near = self._within(offsets)
        if not near.any():
            return None
        distance = np.linalg.norm(offsets[near], axis=1)  # the nearest in 3D: not a fragment above or below it
        return objects[int(np.flatnonzero(near)[np.argmin(distance)])].object_id
