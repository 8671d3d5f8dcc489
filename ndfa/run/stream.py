"""What a pass over recordings needs around the pipeline: the sinks, the run options, the checked
recordings, the frames staged ahead of the detector, and what a session saw."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from ndfa.core.errors import RecordingError
from ndfa.core.events import SESSIONS, DecisionEvent, Event, FrameEvent, ObservationEvent, RegistrationEvent
from ndfa.core.frame import Frame
from ndfa.io.recording import INSTANCES, RecordingReader
from ndfa.io.recording.prefetch import prefetched
from ndfa.perception.segmentation import PlaneTracker
from ndfa.pipeline import ChangeDetectionPipeline, ObservedFrame
from ndfa.run.align import RegistrationMode
from ndfa.run.cloud_align import AlignConfig
from ndfa.run.rate import DEFAULT_RATE_HZ, ODOMETRY_RATE_HZ, tracked_and_used
from ndfa.run.workers import WORKERS
from ndfa.run.world import PoseMode, SessionWorld, UpMode


class Sink(Protocol):
    def log(self, event: Event) -> None: ...
    def close(self) -> None: ...


def emit(event: object, sinks: Sequence[Sink]) -> None:
    for sink in sinks:
        sink.log(event)  # type: ignore[arg-type]  (the session events of `ndfa.core.sessions` too)


@dataclass(frozen=True)
class RunOptions:
    """How recordings are run, beside the pipeline's config: the same for two sessions
    (`ndfa.run.detect.run_detection`) and for more (`ndfa.run.sessions.run_sessions`).

    frame_step, rate_hz: the frames of each recording the pass uses (`ndfa.run.rate`): every
        frame_step-th where it is above 1, else at most rate_hz a second by their timestamps
        (default `DEFAULT_RATE_HZ`; None: every frame).
    odometry_rate_hz: where a session's poses are estimated, the odometry tracks frames at most
        this often, the pass's among them (default `ODOMETRY_RATE_HZ`; None: the pass's frames
        alone, as with a frame step).
    up, poses: what each session's world gets when it lacks it (`ndfa.run.world.prepare_session`).
    check_poses_backward: estimated poses are checked by a second estimate over the frames last
        first (`prepare_session`): a better quality figure for twice the odometry's time.
    registration, align: the scene-level hypothesis of T_rel offered to each pair's detector
        (`ndfa.run.align.registration_prior`).
    workers: processes the run may use; with 2 or more the sessions' poses and the scene
        alignments run ahead of the passes in another (`ndfa.run.workers`); 1: all in this one.
    """

    frame_step: int = 1
    rate_hz: float | None = DEFAULT_RATE_HZ
    odometry_rate_hz: float | None = ODOMETRY_RATE_HZ
    up: UpMode = "auto"
    poses: PoseMode = "auto"
    check_poses_backward: bool = False
    registration: RegistrationMode = "auto"
    align: AlignConfig = field(default_factory=AlignConfig)
    workers: int = WORKERS

    def positions(self, reader: RecordingReader) -> Sequence[int]:
        """The positions of the frames of `reader` the pass uses."""
        return self.tracked_and_used(reader)[1]

    def tracked_and_used(self, reader: RecordingReader) -> tuple[Sequence[int], Sequence[int]]:
        """The positions of the frames of `reader` the odometry tracks and the pass uses (`ndfa.run.rate.tracked_and_used`)."""
        return tracked_and_used(reader, self.frame_step, self.rate_hz, self.odometry_rate_hz)


def open_recordings(paths: Sequence[Path], names: Sequence[str], segment: bool = True
                    ) -> tuple[list[RecordingReader], list[str]]:
    """Open and check every recording; notes say what differs between them but is allowed.

    segment: a recording without instance masks is accepted (its frames are segmented
    geometrically by the pipeline); False: it is an error.
    """
    readers, notes = [], []
    for name, path in zip(names, paths, strict=True):
        reader = RecordingReader(path)
        if not reader.has_instances:
            if not segment:
                raise RecordingError(f"{path}: has no instance masks ({INSTANCES}) and segmentation is off")
            notes.append(f"{who(name)} has no instance masks: each of its frames is segmented geometrically "
                         "(support planes removed, DBSCAN; ndfa.perception.segmentation)")
        if len(reader) == 0:
            raise RecordingError(f"{path}: has no frames")
        readers.append(reader)
    first = [next(reader.frames(stop=1)) for reader in readers]
    for k in range(len(readers) - 1):
        before, after = first[k], first[k + 1]
        if not np.allclose(before.K, after.K) or before.image_size != after.image_size:
            notes.append(f"{names[k]} and {names[k + 1]} cameras differ (intrinsics or image size); each frame is "
                         "back-projected with its own K, so this is supported")
    return readers, notes


def who(name: str) -> str:
    """A session as a note names it: "the source", "session_2"."""
    return f"the {name}" if name in SESSIONS else name


def staged(pipeline: ChangeDetectionPipeline, frames: Iterator[Frame], world: SessionWorld,
           full_reconstruction: bool, overlap: bool = True) -> Iterator[ObservedFrame]:
    """The frames read, perceived and encoded for `pipeline.decide`, in frame order. `overlap`:
    reading and perception run ahead in one thread, encoding in another
    (`ndfa.io.recording.prefetch`), while the caller decides. The stages hold no state (but the
    session's plane tracker, `SegmentationConfig.plane_search_every`, and its recent codes, with
    `PipelineConfig.reuse`) and the detector sees the frames in order, so the events are those of
    `pipeline.process` (whose planes are searched in full in every frame) but for the tracked
    planes; the NDF's
    runtime and much of numpy's work release the GIL, so on two cores the stages run at the same
    time (docs/speed.md)."""
    depth = 4 if overlap else 0
    tracker = pipeline.new_plane_tracker()  # this session's; the perception stage is one thread, in frame order
    perceived = prefetched(_perceived(pipeline, frames, world, tracker), depth)
    reuse = pipeline.new_code_reuse()  # this session's (`PipelineConfig.reuse`); the encoding stage is one thread, in frame order
    return prefetched((pipeline.encode(observed, full_reconstruction, reuse) for observed in perceived), depth)


def _perceived(pipeline: ChangeDetectionPipeline, frames: Iterator[Frame], world: SessionWorld,
               tracker: PlaneTracker | None = None) -> Iterator[ObservedFrame]:
    """Each frame perceived, its stage timings led by "reading" (the reader's work for it:
    decompressing, decoding)."""
    while True:
        started = time.perf_counter()
        frame = next(frames, None)
        if frame is None:
            return
        reading_ms = (time.perf_counter() - started) * 1e3
        observed = pipeline.perceive(world.apply(frame), tracker)
        yield replace(observed, stage_ms={"reading": reading_ms} | observed.stage_ms)


def change_summary(c: DecisionEvent) -> dict:
    """A reported change as the `--json` summaries list it (of `ndfa detect` with two sessions or more)."""
    position = c.center_source if c.center_source is not None else c.center_world
    return {"object": c.object_id, "session": c.session, "kind": c.kind, "frame": c.frame_index,
            "position": [round(float(v), 4) for v in position], "instance_ids": list(c.instance_ids),
            "category": c.category,
            "score": None if np.isnan(c.score) else round(float(c.score), 4)} \
        | ({} if c.angle_deg is None else {"angle_deg": round(c.angle_deg, 1)}) \
        | ({} if c.partner_id is None or c.kind != "moved" else
           {"from_object": c.partner_id, "from_instance_ids": list(c.partner_instance_ids)})


def registration_summary(event: RegistrationEvent) -> dict:
    """An accepted T_rel as the `--json` summaries give it."""
    return {"method": event.method, "inliers": len(event.inlier_pairs), "pairs": event.n_pairs,
            "residual_m": round(float(event.residual_m), 4) if np.isfinite(event.residual_m) else None,
            "frame": event.frame_index,
            "inlier_pairs": [list(p) for p in event.inlier_pairs]} | ({"evidence": event.evidence} if event.evidence else {})


@dataclass
class SessionCounts:
    """What one session's pass saw, to say why it found no objects."""

    frames: int = 0
    frames_with_instances: int = 0
    encoded: int = 0
    skipped: dict[str, int] = field(default_factory=dict)  # reason (numbers stripped) -> views

    def count(self, event: Event) -> None:
        if isinstance(event, FrameEvent):
            self.frames += 1
            instances = event.frame.instances
            self.frames_with_instances += int(instances is not None and bool(instances.any()))
        elif isinstance(event, ObservationEvent) and event.skipped is None:
            self.encoded += 1
        elif isinstance(event, ObservationEvent):
            reason = " ".join(w for w in event.skipped.split(":")[0].split() if not w[0].isdigit())
            self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def why_none(self) -> str:
        """One line: the first stage that came up empty."""
        if self.frames == 0:
            return "no frames were read"
        if self.frames_with_instances == 0:
            return (f"none of its {self.frames} frames has an object mask or segment (without masks: no support "
                    "plane with object-sized clusters on it was found; is the world z-up? see `ndfa info`)")
        if self.encoded == 0:
            reasons = ", ".join(f"{n} {r}" for r, n in sorted(self.skipped.items(), key=lambda x: -x[1]))
            return f"every view of an object was skipped ({reasons})"
        return f"{self.encoded} views were encoded but none was kept (each object needs repeated views)"
