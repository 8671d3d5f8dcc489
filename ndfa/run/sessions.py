"""`ndfa detect S0.mcap S1.mcap S2.mcap ...`: the changes between consecutive sessions, and every
object's history over all of them.

Two sessions stay `ndfa.run.detect.run_detection`. With more, each session's pass runs the pipeline
once (perception and the NDF encode each session once): the first builds its object map; every
later one is the target pass of the pair (session before -> this one), whose detector gets the
session before as its source by replaying that session's kept measurements (as
`ndfa.run.replay` does), so the pair's decisions are made online, frame by frame, as in a
two-session run. Each pair gets the scene-level registration hypothesis of `ndfa.run.align`.

Every session is registered to the first by composing the pair registrations (T_{0<-k} = T_{0<-k-1}
T_rel); the objects are linked over the sessions through the pair decisions (`ndfa.run.history`).
The sinks see one stream: the sessions in order, each event's `session` its name (`session_0`,
...), every `*_source` position in the first session's world, and the events of
`ndfa.core.sessions` (session start, pair, history).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ndfa.change.associate import Measurement
from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.core.conventions import is_visible
from ndfa.core.errors import RecordingError
from ndfa.core.events import (
    AssociationEvent,
    DecisionEvent,
    Event,
    GraphEvent,
    ObservationEvent,
    RegistrationEvent,
    TimingEvent,
)
from ndfa.core.geometry import transform_points
from ndfa.core.progress import LabelledProgress
from ndfa.core.sessions import HistoryEvent, HistoryRow, PairEvent, SessionStartEvent
from ndfa.eval.scoring import changed_instances, score
from ndfa.io.recording import INSTANCES, RecordingReader
from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
from ndfa.run.align import SceneAlignment, registration_prior
from ndfa.run.detect import RunOptions, SessionCounts, Sink, _registration_summary, change_summary, staged
from ndfa.run.history import LinkConfig, SessionObjects, compose_placements, link_history
from ndfa.run.world import SessionWorld, prepare_session


@dataclass
class PairResult:
    """One pair of consecutive sessions: what its detector reported, as a two-session run reports it."""

    index: int
    source: str
    target: str
    changes: list[DecisionEvent]        # reported changes (sessions named, positions in the first session's world)
    decisions: list[DecisionEvent]      # every decision, as the detector made it (sessions "source"/"target")
    registration: dict | None           # the accepted T_rel (target -> source session), or None
    alignment: SceneAlignment | None
    score: object | None = None         # `Score` (masks) or `PositionScore` (segmented), with ground truth
    notes: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        return f"{self.index}-{self.index + 1}"

    def as_dict(self) -> dict:
        out = {"pair": self.label, "source": self.source, "target": self.target,
               "changes": [change_summary(c) for c in self.changes], "registration": self.registration,
               "scene_alignment": None if self.alignment is None else self.alignment.as_dict(), "notes": self.notes}
        if self.score is not None:
            out["score"] = self.score.as_dict()  # type: ignore[attr-defined]
        return out


@dataclass
class SessionsResult:
    names: list[str]
    paths: list[Path]
    frames: dict[str, int]
    objects: dict[str, int]
    seconds: dict[str, float]
    stage_ms: dict[str, float]                   # mean ms per frame of every session, per stage
    worlds: dict[str, SessionWorld]
    placements: list[np.ndarray | None]          # T_{0<-k}: session k's world in the first's
    pairs: list[PairResult]
    history: list[HistoryRow]
    notes: list[str] = field(default_factory=list)
    history_score: object | None = None          # `ndfa.eval.history.HistoryScore`, with ground truth

    @property
    def changes(self) -> list[DecisionEvent]:
        return [c for pair in self.pairs for c in pair.changes]

    @property
    def fps(self) -> float:
        seconds = sum(self.seconds.values())
        return sum(self.frames.values()) / seconds if seconds else float("nan")

    def summary(self) -> dict:
        """The `--json` summary of a many-session run."""
        out = {
            "sessions": [{"name": name, "path": str(path), "frames": self.frames[name], "objects": self.objects[name],
                          "world": self.worlds[name].as_dict(),
                          "placement": None if placement is None else np.round(placement, 6).tolist()}
                         for name, path, placement in zip(self.names, self.paths, self.placements, strict=True)],
            "frames": sum(self.frames.values()),
            "fps": self.fps,
            "stage_ms": self.stage_ms,
            "pairs": [pair.as_dict() for pair in self.pairs],
            "changes": [change_summary(c) | {"pair": pair.label} for pair in self.pairs for c in pair.changes],
            "history": [row.as_dict() for row in self.history],
            "notes": self.notes,
        }
        if self.history_score is not None:
            out["history_score"] = self.history_score.as_dict()  # type: ignore[attr-defined]
        return out


def session_names(n: int) -> list[str]:
    return [f"session_{k}" for k in range(n)]


def open_sessions(paths: list[Path], segment: bool = True) -> tuple[list[RecordingReader], list[str]]:
    """Open and check every recording (as `ndfa.run.detect.open_pair` does for two)."""
    readers, notes = [], []
    for index, path in enumerate(paths):
        reader = RecordingReader(path)
        if not reader.has_instances:
            if not segment:
                raise RecordingError(f"{path}: has no instance masks ({INSTANCES}) and segmentation is off")
            notes.append(f"session {index} has no instance masks: each of its frames is segmented geometrically")
        if len(reader) == 0:
            raise RecordingError(f"{path}: has no frames")
        readers.append(reader)
    return readers, notes


def run_sessions(
    paths: list[Path],
    config: PipelineConfig = PipelineConfig(),
    sinks: list[Sink] = (),
    options: RunOptions = RunOptions(),
    on_frame: LabelledProgress | None = None,  # (session name, frames done, frames in session)
    pipeline: ChangeDetectionPipeline | None = None,
    on_world: Callable[[SessionWorld], None] | None = None,
    on_alignment: Callable[[str, SceneAlignment], None] | None = None,  # (pair label, hypothesis)
) -> SessionsResult:
    """The sessions' passes in order (see the module docstring); sinks are closed at the end, also
    when interrupted."""
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise RecordingError(f"a change needs two sessions, got {len(paths)} recording(s)")
    readers, notes = open_sessions(paths, segment=config.segmentation is not None)
    names = session_names(len(paths))
    worlds: dict[str, SessionWorld] = {}
    for name, reader in zip(names, readers):
        worlds[name] = prepare_session(reader, name, up=options.up, poses=options.poses)
        if on_world is not None:
            on_world(worlds[name])
    pipeline = pipeline or ChangeDetectionPipeline(config)
    kept: list[list[list[Measurement]]] = []     # per session, per frame: the measurements the detector took
    maps, pairs, transforms = [], [], []
    frames, seconds, stage_totals = {}, {}, {}
    visible: list[set[int]] = []
    masks: list[dict[int, dict[int, int]]] = []  # per session: object -> mask id -> measurements it took
    seen = [SessionCounts() for _ in names]
    try:
        for index, (name, reader) in enumerate(zip(names, readers)):
            _emit(SessionStartEvent(index=index, names=tuple(names)), sinks)
            pair: PairRun | None = None
            if index == 0:
                pipeline.detector = ChangeDetector(config.detector)
            else:
                pair = PairRun.start(index - 1, names, readers, worlds, kept[-1], config, options,
                                     compose_placements(transforms)[index - 1])
                if pair.alignment is not None and on_alignment is not None:
                    on_alignment(pair.label, pair.alignment)
                pipeline.detector = pair.detector
                _emit(pair.event, sinks)
            role = "source" if pair is None else "target"
            kept.append([])
            visible.append(set())
            masks.append({})
            total = len(range(0, len(reader), options.frame_step))
            started, count = time.perf_counter(), 0
            # Without sinks, reconstructions only as far as decisions need (`ChangeDetectionPipeline.encode`).
            for observed in staged(pipeline, reader.frames(step=options.frame_step), worlds[name], full_reconstruction=bool(sinks)):
                measurements: list[Measurement] = []
                for event in pipeline.decide(role, observed):
                    seen[index].count(event)
                    if isinstance(event, ObservationEvent):
                        if event.skipped is None:
                            measurements.append(Measurement.of(event))
                        if is_visible(event.n_pixels):
                            visible[index].add(event.instance_id)
                    if isinstance(event, AssociationEvent):
                        taken = masks[index].setdefault(event.object_id, {})
                        taken[event.instance_id] = taken.get(event.instance_id, 0) + 1
                    if isinstance(event, TimingEvent):
                        for stage, ms in event.stage_ms.items():
                            stage_totals[stage] = stage_totals.get(stage, 0.0) + ms
                    _emit(pair.relabel(event) if pair is not None else _named(event, name), sinks)
                if measurements:
                    kept[-1].append(measurements)
                count += 1
                if on_frame is not None:
                    on_frame(name, count, total)
            frames[name], seconds[name] = count, time.perf_counter() - started
            if pair is None:
                maps.append(pipeline.detector.source)
                continue
            for event in pipeline.finish():
                _emit(pair.relabel(event), sinks)
            maps.append(pipeline.detector.target)
            pairs.append(pair)
            transforms.append(None if pair.detector.registration is None else pair.detector.registration.transform)
        placements = compose_placements(transforms)
        objects = [SessionObjects({i: o.center_world for i, o in m.objects.items()},
                                  {i: o.shape_code for i, o in m.objects.items()},
                                  {i: max(taken, key=taken.__getitem__) for i, taken in session_masks.items()})
                   for m, session_masks in zip(maps, masks)]
        link = LinkConfig(shape_similarity=config.detector.association.shape_similarity)
        history = link_history(names, objects, placements, [p.decisions for p in pairs], link)
        _emit(HistoryEvent(rows=tuple(history), names=tuple(names)), sinks)
    finally:
        for sink in sinks:
            sink.close()

    for index, (name, session_map) in enumerate(zip(names, maps)):
        if not session_map.objects:
            notes.append(f"{name} has no objects: {seen[index].why_none()}")
    for k, placement in enumerate(placements):
        if placement is None and (k == 0 or placements[k - 1] is not None):
            notes.append(f"{names[k]} could not be registered to {names[k - 1]} (no registration found): it and "
                         "the sessions after it have no positions in the first session's world")
    results = [p.result(readers, worlds, visible, notes) for p in pairs]
    result = SessionsResult(
        names=names, paths=paths, frames=frames, objects={n: len(m) for n, m in zip(names, maps)},
        seconds=seconds, stage_ms={s: t / max(sum(frames.values()), 1) for s, t in stage_totals.items()},
        worlds=worlds, placements=placements, pairs=results, history=history, notes=notes)
    truth = readers[-1].ground_truth
    if truth is not None and isinstance(truth.get("sessions"), dict) and all(r.has_instances for r in readers):
        from ndfa.eval.history import score_history

        result.history_score = score_history(history, truth["sessions"],
                                             {n: v for n, v in zip(names, visible)})
    return result


@dataclass
class PairRun:
    """The detector of one pair while the target session's pass runs, and what it decided."""

    index: int
    names: list[str]
    detector: ChangeDetector
    alignment: SceneAlignment | None
    placement: np.ndarray | None      # the source session's T_{0<-k}
    event: PairEvent
    decisions: list[DecisionEvent] = field(default_factory=list)
    registration: RegistrationEvent | None = None
    truth: dict | None = None

    @property
    def label(self) -> str:
        return f"{self.index}-{self.index + 1}"

    @classmethod
    def start(cls, index: int, names: list[str], readers: list[RecordingReader], worlds: dict[str, SessionWorld],
              source: list[list[Measurement]], config: PipelineConfig, options: RunOptions,
              placement: np.ndarray | None) -> PairRun:
        """The pair's detector with the source session replayed into it and the pair's registration prior."""
        detector = ChangeDetector(config.detector)
        pair_worlds = {"source": worlds[names[index]], "target": worlds[names[index + 1]]}
        alignment = registration_prior(readers[index], readers[index + 1], pair_worlds, options.registration,
                                       options.align)
        if alignment is not None:
            prior = alignment.prior()
            if prior is not None:
                detector.add_registration_prior(prior)
        for measurements in source:
            detector.add_source(measurements)  # its events were the source session's own pass
        truth = readers[index + 1].ground_truth
        truth = truth if truth is not None and "objects" in truth else None
        event = PairEvent(index=index, source=names[index], target=names[index + 1], placement=placement,
                          truth=None if truth is None else changed_instances(truth))
        return cls(index, names, detector, alignment, placement, event, truth=truth)

    def relabel(self, event: Event) -> Event:
        """The event as the sinks get it: sessions named, source-world positions in the first session's
        world. Keeps the pair's decisions and registration on the way."""
        if isinstance(event, DecisionEvent):
            self.decisions.append(event)
        if isinstance(event, RegistrationEvent) and event.accepted:
            self.registration = event
        return self.to_first(_named(event, self.names[self.index + (0 if _role(event) == "source" else 1)]))

    def to_first(self, event: Event) -> Event:
        """Source-world positions of `event` in the first session's world."""
        placement = self.placement
        if placement is None or not isinstance(event, (DecisionEvent, GraphEvent, RegistrationEvent)):
            return event
        rotation = placement[:3, :3]
        if isinstance(event, DecisionEvent):
            if event.center_source is None:
                return event
            return dataclasses.replace(event, center_source=_point(placement, event.center_source))
        if isinstance(event, GraphEvent):
            return dataclasses.replace(
                event, center_source=_point(placement, event.center_source),
                partner_center_source=_point(placement, event.partner_center_source),
                target_edges_source=np.asarray(event.target_edges_source).reshape(-1, 3) @ rotation.T,
                source_edges=np.asarray(event.source_edges).reshape(-1, 3) @ rotation.T)
        return dataclasses.replace(
            event, transform=None if event.transform is None else placement @ event.transform,
            source_centers=transform_points(placement, np.asarray(event.source_centers).reshape(-1, 3)))

    def result(self, readers: list[RecordingReader], worlds: dict[str, SessionWorld], visible: list[set[int]],
               notes: list[str]) -> PairResult:
        """The pair's report, scored against the target recording's ground truth when it has one."""
        changes = [self.to_first(_named(c, self.names[self.index + (0 if c.session == "source" else 1)]))
                   for c in reported_changes(self.decisions)]
        pair_notes: list[str] = []
        if self.detector.registration is None and self.detector.target.objects:
            pair_notes.append("no registration between the sessions was found: no target object was tested")
        result = PairResult(self.index, self.names[self.index], self.names[self.index + 1], changes, self.decisions,
                            None if self.registration is None else _registration_summary(self.registration),
                            self.alignment, notes=pair_notes)
        source, target = readers[self.index], readers[self.index + 1]
        if self.truth is not None:
            original = reported_changes(self.decisions)
            if source.has_instances and target.has_instances:
                result.score = score([i for c in original for i in c.reported_instances], self.truth,
                                     {"source": visible[self.index], "target": visible[self.index + 1]})
            else:
                from ndfa.run.position_score import score_segmented_run

                result.score = score_segmented_run(
                    original, self.detector, {"source": source, "target": target},
                    {"source": worlds[self.names[self.index]], "target": worlds[self.names[self.index + 1]]},
                    pair_notes)
        notes.extend(f"pair {self.label}: {note}" for note in pair_notes)
        return result


def _role(event: Event) -> str:
    return getattr(event, "session", "target")


def _named(event: Event, name: str) -> Event:
    """`event` with its `session` set to the session's name (events without one as they are)."""
    if not hasattr(event, "session"):
        return event
    return dataclasses.replace(event, session=name)  # type: ignore[call-arg]


def _point(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    return transform_points(pose, np.asarray(point, dtype=float)[None])[0]


def _emit(event: object, sinks: list[Sink]) -> None:
    for sink in sinks:
        sink.log(event)  # type: ignore[arg-type]


__all__ = ["PairResult", "SessionsResult", "run_sessions"]
