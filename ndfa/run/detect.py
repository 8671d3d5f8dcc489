"""`ndfa detect`: run the pipeline over a source and a target recording, feed the sinks, score the result.

This is the I/O shell around `ChangeDetectionPipeline`: it opens and checks the recordings, streams
their frames (source first, then target), hands every event to every sink, and summarises the
reported changes (scored when the target carries ground truth).

Before the passes it may hand the detector a scene-level hypothesis of T_rel (`ndfa.run.align`:
the sessions' shared world, or the alignment of their scene clouds), which the object pairs verify;
the result says which registration was used and with how many inliers.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from ndfa.change.detector import reported_changes
from ndfa.core.conventions import is_visible
from ndfa.core.errors import RecordingError
from ndfa.core.events import DecisionEvent, Event, FrameEvent, ObservationEvent, RegistrationEvent, TimingEvent
from ndfa.core.frame import Frame
from ndfa.core.progress import LabelledProgress
from ndfa.eval.scoring import Score, rotated_reports, score
from ndfa.io.recording import INSTANCES, RecordingReader
from ndfa.io.recording.prefetch import prefetched
from ndfa.pipeline import ChangeDetectionPipeline, ObservedFrame, PipelineConfig
from ndfa.run.align import AlignConfig, RegistrationMode, SceneAlignment, registration_prior
from ndfa.run.world import PoseMode, SessionWorld, UpMode, prepare_session


class Sink(Protocol):
    def log(self, event: Event) -> None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class RunOptions:
    """How recordings are run, beside the pipeline's config: the same for a pair (`run_detection`)
    and for many sessions (`ndfa.run.sessions.run_sessions`).

    frame_step: every n-th frame of each recording.
    up, poses: what each session's world gets when it lacks it (`ndfa.run.world.prepare_session`).
    registration, align: the scene-level hypothesis of T_rel offered to the detector
        (`ndfa.run.align.registration_prior`).
    """

    frame_step: int = 1
    up: UpMode = "auto"
    poses: PoseMode = "auto"
    registration: RegistrationMode = "auto"
    align: AlignConfig = field(default_factory=AlignConfig)


@dataclass
class DetectionResult:
    changes: list[DecisionEvent]                 # reported changes: added / moved (target), removed (source)
    frames: dict[str, int]
    objects: dict[str, int]
    seconds: dict[str, float]                    # wall time per session pass
    stage_ms: dict[str, float]                   # mean ms per target frame, per stage
    score: Score | None = None
    notes: list[str] = field(default_factory=list)
    worlds: dict[str, SessionWorld] = field(default_factory=dict)  # poses and up each session ran on
    registration: dict | None = None             # the accepted T_rel: method, inliers, frame (None: none found)
    alignment: SceneAlignment | None = None      # the scene-level hypothesis offered to the detector, if any
    object_centers: dict[str, np.ndarray] = field(default_factory=dict)  # session -> (n, 3) centers, own world
    object_measurements: dict[str, np.ndarray] = field(default_factory=dict)  # session -> (n,) measurements each

    @property
    def target_fps(self) -> float:
        return self.frames["target"] / self.seconds["target"] if self.seconds.get("target") else float("nan")

    def summary(self) -> dict:
        """The `--json` summary."""
        out = {}
        if self.score is not None:
            out |= self.score.as_dict()
        out |= {
            "frames": self.frames["source"] + self.frames["target"],
            "frames_source": self.frames["source"], "frames_target": self.frames["target"],
            "objects_source": self.objects["source"], "objects_target": self.objects["target"],
            "fps": self.target_fps,
            "stage_ms": self.stage_ms,
            "changes": [change_summary(c) for c in self.changes],
            "notes": self.notes,
            "world": {session: world.as_dict() for session, world in self.worlds.items()},
            "registration": self.registration,
            "scene_alignment": None if self.alignment is None else self.alignment.as_dict(),
        }
        return out

    def describe_registration(self) -> str:
        """One line: which registration the target was tested with."""
        if self.registration is None:
            return "registration: none found"
        r = self.registration
        residual = "" if r["residual_m"] is None else f", residual {r['residual_m'] * 100:.1f} cm"
        return (f"registration: {r['method']}, {r['inliers']} inlier object pairs of {r['pairs']}{residual}, "
                f"from target frame {r['frame']}")


def change_summary(c: DecisionEvent) -> dict:
    """A reported change as the `--json` summaries list it (of `ndfa detect` with two sessions or more)."""
    position = c.center_source if c.center_source is not None else c.center_world
    return {"object": c.object_id, "session": c.session, "kind": c.kind, "frame": c.frame_index,
            "position": [round(float(v), 4) for v in position], "instance_ids": list(c.instance_ids),
            "score": None if np.isnan(c.score) else round(float(c.score), 4)} \
        | ({} if c.angle_deg is None else {"angle_deg": round(c.angle_deg, 1)})


def open_pair(source: Path, target: Path, segment: bool = True) -> tuple[RecordingReader, RecordingReader, list[str]]:
    """Open and check both recordings; notes say what differs between them but is allowed.

    segment: a recording without instance masks is accepted (its frames are segmented
    geometrically by the pipeline); False: it is an error.
    """
    readers, notes = {}, []
    for name, path in (("source", source), ("target", target)):
        reader = RecordingReader(path)
        if not reader.has_instances:
            if not segment:
                raise RecordingError(f"{path}: has no instance masks ({INSTANCES}) and segmentation is off")
            notes.append(f"the {name} has no instance masks: each of its frames is segmented geometrically "
                         "(support planes removed, DBSCAN; ndfa.perception.segmentation)")
        if len(reader) == 0:
            raise RecordingError(f"{path}: has no frames")
        readers[name] = reader
    first = {name: next(r.frames(stop=1)) for name, r in readers.items()}
    if not np.allclose(first["source"].K, first["target"].K) or first["source"].image_size != first["target"].image_size:
        notes.append("source and target cameras differ (intrinsics or image size); each frame is "
                     "back-projected with its own K, so this is supported")
    return readers["source"], readers["target"], notes


def run_detection(
    source: Path,
    target: Path,
    config: PipelineConfig = PipelineConfig(),
    sinks: list[Sink] = (),
    options: RunOptions = RunOptions(),
    on_frame: LabelledProgress | None = None,  # (session, frames done, frames in session)
    pipeline: ChangeDetectionPipeline | None = None,
    on_world: Callable[[SessionWorld], None] | None = None,
    on_alignment: Callable[[SceneAlignment], None] | None = None,
    full_reconstruction: bool | None = None,
    overlap: bool = True,
) -> DetectionResult:
    """Source pass, target pass, finish. Sinks are closed at the end, also when interrupted.

    Before its pass, each session gets what it lacks (`ndfa.run.world`): poses when it has none,
    world up when its world is not known to be z-up (`options.up`, `options.poses`: the modes
    there); `on_world` hears what was used, as soon as it is known. Then the scene-level hypothesis
    of T_rel that `options.registration` asks for (`ndfa.run.align.registration_prior`) is computed and,
    when it holds, handed to the detector; `on_alignment` hears it. `full_reconstruction`
    (`ChangeDetectionPipeline.process`): None, when there are sinks to see the reconstructions.
    `overlap`: frames are read, perceived and encoded ahead in threads (`staged`); False: one
    frame after the other in this thread (the same events)."""
    source_reader, target_reader, notes = open_pair(Path(source), Path(target), segment=config.segmentation is not None)
    worlds = {}
    for session, reader in (("source", source_reader), ("target", target_reader)):
        worlds[session] = prepare_session(reader, session, up=options.up, poses=options.poses)
        if on_world is not None:
            on_world(worlds[session])
    pipeline = pipeline or ChangeDetectionPipeline(config)
    alignment = registration_prior(source_reader, target_reader, worlds, options.registration, options.align)
    if alignment is not None:
        if on_alignment is not None:
            on_alignment(alignment)
        prior = alignment.prior()
        if prior is not None:
            pipeline.detector.add_registration_prior(prior)
    frames, seconds, stage_totals, decisions, changes = {}, {}, {}, [], []
    registration_event: RegistrationEvent | None = None  # the last accepted: the T_rel of the last decisions
    visible: dict[str, set[int]] = {"source": set(), "target": set()}  # for scoring (`ndfa.eval.scoring`)
    seen = {"source": SessionCounts(), "target": SessionCounts()}     # to explain a session without objects
    # Without sinks nobody sees the reconstructions: they are decoded only as far as decisions need.
    full = bool(sinks) if full_reconstruction is None else full_reconstruction
    try:
        for session, reader in (("source", source_reader), ("target", target_reader)):
            total = len(range(0, len(reader), options.frame_step))
            started, count = time.perf_counter(), 0
            for observed in staged(pipeline, reader.frames(step=options.frame_step), worlds[session], full, overlap):
                for event in pipeline.decide(session, observed):
                    _emit(event, sinks)
                    seen[session].count(event)
                    if isinstance(event, DecisionEvent):
                        decisions.append(event)
                    if isinstance(event, RegistrationEvent) and event.accepted:
                        registration_event = event
                    if isinstance(event, ObservationEvent) and is_visible(event.n_pixels):
                        visible[session].add(event.instance_id)
                    if isinstance(event, TimingEvent) and session == "target":
                        for stage, ms in event.stage_ms.items():
                            stage_totals[stage] = stage_totals.get(stage, 0.0) + ms
                count += 1
                if on_frame is not None:
                    on_frame(session, count, total)
            frames[session], seconds[session] = count, time.perf_counter() - started
        final_events = pipeline.finish()
        for event in final_events:
            _emit(event, sinks)
        changes = reported_changes(decisions + [e for e in final_events if isinstance(e, DecisionEvent)])
    finally:
        for sink in sinks:
            sink.close()

    detector = pipeline.detector
    for session, session_map in (("source", detector.source), ("target", detector.target)):
        if not session_map.objects:
            notes.append(f"the {session} has no objects: {seen[session].why_none()}")
    if detector.registration is None and detector.target.objects:
        notes.append("no registration between the sessions was found: no target object was tested, "
                     "so only the source's observed objects could be reported")
        if alignment is not None and not alignment.ok:
            notes.append(f"the scene-level hypothesis did not hold ({alignment.describe()})")
        if alignment is not None and not alignment.ok and alignment.method == "shared world" \
                and options.registration == "auto":
            notes.append("the sessions' poses are given but do not share one world: --registration scene "
                         "aligns their scene clouds instead")
    result = DetectionResult(
        changes=changes,
        frames=frames,
        objects={"source": len(detector.source), "target": len(detector.target)},
        seconds=seconds,
        stage_ms={stage: total / max(frames["target"], 1) for stage, total in stage_totals.items()},
        notes=notes,
        worlds=worlds,
        registration=None if registration_event is None else _registration_summary(registration_event),
        alignment=alignment,
        object_centers={name: np.array([o.center_world for o in m.objects.values()]).reshape(-1, 3)
                        for name, m in (("source", detector.source), ("target", detector.target))},
        object_measurements={name: np.array([o.n_measurements for o in m.objects.values()], dtype=int)
                             for name, m in (("source", detector.source), ("target", detector.target))},
    )
    truth = target_reader.ground_truth
    segmented = not (source_reader.has_instances and target_reader.has_instances)
    if truth is not None and "objects" in truth and segmented:
        # Segment labels are no instance ids: each report is named by the item at its center.
        from ndfa.run.position_score import score_segmented_run

        result.score = score_segmented_run(changes, detector, {"source": source_reader, "target": target_reader},
                                           worlds, notes)
    elif truth is not None and "objects" in truth:
        result.score = score([i for c in changes for i in c.reported_instances], truth, visible, rotated_reports(changes))
    return result


def staged(pipeline: ChangeDetectionPipeline, frames: Iterator[Frame], world: SessionWorld,
           full_reconstruction: bool, overlap: bool = True) -> Iterator[ObservedFrame]:
    """The frames read, perceived and encoded for `pipeline.decide`, in frame order. `overlap`:
    reading and perception run ahead in one thread, encoding in another
    (`ndfa.io.recording.prefetch`), while the caller decides. The stages hold no state and the
    detector sees the frames in order, so the events are those of `pipeline.process`; the NDF's
    runtime and much of numpy's work release the GIL, so on two cores the stages run at the same
    time (docs/speed.md)."""
    depth = 4 if overlap else 0
    perceived = prefetched((pipeline.perceive(world.apply(frame)) for frame in frames), depth)
    return prefetched((pipeline.encode(observed, full_reconstruction) for observed in perceived), depth)


def _registration_summary(event: RegistrationEvent) -> dict:
    return {"method": event.method, "inliers": len(event.inlier_pairs), "pairs": event.n_pairs,
            "residual_m": round(float(event.residual_m), 4) if np.isfinite(event.residual_m) else None,
            "frame": event.frame_index,
            "inlier_pairs": [list(p) for p in event.inlier_pairs]}


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


def _emit(event, sinks) -> None:
    for sink in sinks:
        sink.log(event)
