"""The one pass over sessions: `ndfa detect S0.mcap S1.mcap ...`, two sessions the case N = 2.

Each session's pass runs the pipeline once (perception and the NDF encode each session once). Each
pair of consecutive sessions (k -> k+1) has its own detector: session k's measurements are its
source pass, session k+1's its target pass, so a session between two pairs feeds both detectors,
frame by frame (`ChangeDetectionPipeline.decide`), and every pair's decisions are made online, as
in a two-session run. Before its target pass, a pair's detector gets the scene-level registration
hypothesis of `ndfa.run.align`.

Every session is registered to the first by composing the pair registrations (T_{0<-k} = T_{0<-k-1}
T_rel); the objects are linked over the sessions through the pair decisions (`ndfa.run.history`).
The sinks see one stream: the sessions in order, each event's `session` its name, every `*_source`
position in the first session's world. A run of more than two sessions (`run_sessions`) names them
`session_0`, ... and adds the events of `ndfa.core.sessions` (session start, pair, history); a run
of two (`ndfa.run.detect.run_detection`) names them "source" and "target", as the detector does.

The results are not scored here: `ndfa.eval.runs` scores them against the recordings' ground truth.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ndfa.change.associate import SessionMap
from ndfa.core.conventions import is_visible
from ndfa.core.errors import RecordingError
from ndfa.core.events import AssociationEvent, DecisionEvent, ObservationEvent, TimingEvent
from ndfa.core.progress import LabelledProgress
from ndfa.core.sessions import HistoryEvent, HistoryRow, PairEvent, SessionStartEvent
from ndfa.io.recording import RecordingReader
from ndfa.io.recording.ground_truth import changed_instances, identical_moves
from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
from ndfa.run.align import SceneAlignment
from ndfa.run.history import LinkConfig, SessionObjects, compose_placements, link_history
from ndfa.run.pair import PairResult, named
from ndfa.run.pose_verdict import pose_quality_event
from ndfa.run.stream import (
    RunOptions,
    SessionCounts,
    Sink,
    change_summary,
    emit,
    open_recordings,
    staged,
    who,
)
from ndfa.run.workers import Ahead
from ndfa.run.world import SessionWorld


@dataclass
class SessionsResult:
    names: list[str]
    paths: list[Path]
    readers: list[RecordingReader] = field(repr=False)
    frames: dict[str, int]
    seconds: dict[str, float]                    # wall time per session pass
    stage_totals: dict[str, dict[str, float]]    # per session: stage -> ms summed over its frames
    worlds: dict[str, SessionWorld]
    placements: list[np.ndarray | None]          # T_{0<-k}: session k's world in the first's
    pairs: list[PairResult]
    maps: list[SessionMap]                       # each session's objects
    visible: dict[str, set[int]]                 # per session: the mask ids seen (`is_visible`), for scoring
    history: list[HistoryRow]
    run_notes: list[str] = field(default_factory=list)
    history_score: object | None = None          # `ndfa.eval.history.HistoryScore`, by `ndfa.eval.runs`

    @property
    def notes(self) -> list[str]:
        """The run's notes, then each pair's (prefixed with it when there are more than two sessions)."""
        many = len(self.names) > 2
        return self.run_notes + [f"pair {p.label}: {note}" if many else note for p in self.pairs for note in p.notes]

    @property
    def objects(self) -> dict[str, int]:
        return {name: len(m) for name, m in zip(self.names, self.maps)}

    @property
    def stage_ms(self) -> dict[str, float]:
        """Mean ms per frame of every session, per stage."""
        totals: dict[str, float] = {}
        for session in self.stage_totals.values():
            for stage, ms in session.items():
                totals[stage] = totals.get(stage, 0.0) + ms
        return {stage: total / max(sum(self.frames.values()), 1) for stage, total in totals.items()}

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
            "sessions": [{"name": name, "path": str(path), "frames": self.frames[name], "objects": len(session_map),
                          "world": self.worlds[name].as_dict(),
                          "placement": None if placement is None else np.round(placement, 6).tolist()}
                         for name, path, placement, session_map
                         in zip(self.names, self.paths, self.placements, self.maps, strict=True)],
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


def run_sessions(
    paths: Sequence[Path],
    config: PipelineConfig = PipelineConfig(),
    sinks: Sequence[Sink] = (),
    options: RunOptions = RunOptions(),
    on_frame: LabelledProgress | None = None,  # (session name, frames done, frames in session)
    pipeline: ChangeDetectionPipeline | None = None,
    on_world: Callable[[SessionWorld], None] | None = None,
    on_alignment: Callable[[str, SceneAlignment], None] | None = None,  # (pair label, hypothesis)
) -> SessionsResult:
    """The sessions' pass (see the module docstring), the sessions named `session_0`, ...; sinks
    are closed at the end, also when interrupted."""
    if len(paths) < 2:
        raise RecordingError(f"a change needs two sessions, got {len(paths)} recording(s)")
    return session_pass(paths, session_names(len(paths)), config, sinks, options, on_frame, pipeline, on_world,
                        on_alignment, session_events=True)


def session_pass(
    paths: Sequence[Path],
    names: Sequence[str],
    config: PipelineConfig,
    sinks: Sequence[Sink],
    options: RunOptions,
    on_frame: LabelledProgress | None = None,
    pipeline: ChangeDetectionPipeline | None = None,
    on_world: Callable[[SessionWorld], None] | None = None,
    on_alignment: Callable[[str, SceneAlignment], None] | None = None,
    full_reconstruction: bool | None = None,
    overlap: bool = True,
    session_events: bool = True,
) -> SessionsResult:
    """Every session's pass in order, each pair's detector fed on the way; sinks are closed at the
    end, also when interrupted.

    Before its pass, each session gets what it lacks (`ndfa.run.world`): poses when it has none,
    world up when its world is not known to be z-up (`options.up`, `options.poses`); `on_world`
    hears what was used, as soon as the pass takes it; `on_alignment` hears each pair's scene-level
    hypothesis of T_rel (`options.registration`). Which of these run ahead in a worker process
    (`options.workers`) is `ndfa.run.workers`'s to decide; the results are the same. `full_reconstruction`
    (`ChangeDetectionPipeline.process`): None, when there are sinks to see the reconstructions.
    `overlap`: frames are read, perceived and encoded ahead in threads (`staged`); False: one
    frame after the other in this thread (the same events). `session_events`: the sinks also get
    the events of `ndfa.core.sessions`."""
    paths, names = [Path(p) for p in paths], list(names)
    readers, notes = open_recordings(paths, names, segment=config.segmentation is not None)
    pipeline = pipeline or ChangeDetectionPipeline(config)
    # Without sinks nobody sees the reconstructions: they are decoded only as far as decisions need.
    full = bool(sinks) if full_reconstruction is None else full_reconstruction
    # A detector that takes no priors (`PriorConfig.enabled` off: the paper's) is offered none.
    registration = options.registration if pipeline.config.detector.priors.enabled else "objects"
    # Where the worlds and the scene alignments run (here, or ahead in a worker process): `ndfa.run.workers`.
    # The frames each session's odometry tracks and its pass uses (`options.frame_step`, `options.rate_hz`, ...).
    tracked, used = zip(*(options.tracked_and_used(reader) for reader in readers))
    ahead = Ahead(readers, names, options.workers, options.up, options.poses, options.check_poses_backward,
                  registration, options.align, tracked)
    worlds: dict[str, SessionWorld] = {}

    def know(index: int) -> None:
        name = names[index]
        worlds[name] = ahead.world(index)
        if on_world is not None:
            on_world(worlds[name])
        if worlds[name].pose_quality is not None:
            emit(pose_quality_event(worlds[name]), sinks)
    pairs: list[PairResult] = []
    frames: dict[str, int] = {}
    seconds: dict[str, float] = {}
    stage_totals: dict[str, dict[str, float]] = {name: {} for name in names}
    visible: dict[str, set[int]] = {name: set() for name in names}
    masks: list[dict[int, dict[int, int]]] = [{} for _ in names]  # per session: object -> mask id -> measurements
    seen = [SessionCounts() for _ in names]                       # to explain a session without objects
    transforms: list[np.ndarray | None] = []
    try:
        for index in ahead.before_passes():
            know(index)
        for index, (name, reader) in enumerate(zip(names, readers)):
            if name not in worlds:
                know(index)
            if session_events:
                emit(SessionStartEvent(index=index, names=tuple(names)), sinks)
            ending = pairs[index - 1] if index > 0 else None  # the pair whose target this session is
            if ending is not None:
                placement = compose_placements(transforms)[index - 1]
                alignment = ending.start_target(ahead.alignment(index - 1), placement)
                if alignment is not None and on_alignment is not None:
                    on_alignment(ending.label, alignment)
                if session_events:
                    truth = reader.ground_truth if reader.ground_truth and "objects" in reader.ground_truth else None
                    emit(PairEvent(index=ending.index, source=ending.source, target=ending.target,
                                   placement=placement, truth=changed_instances(truth) if truth else None,
                                   identical_moves=identical_moves(truth) if truth else frozenset()), sinks)
            starting = None  # the pair whose source this session is
            if index < len(names) - 1:
                starting = PairResult(index, names[index], names[index + 1], pipeline.new_detector())
                pairs.append(starting)
            total = len(used[index])
            started, count = time.perf_counter(), 0
            for observed in staged(pipeline, reader.frames(positions=used[index]), worlds[name], full, overlap):
                ahead.poll(index)  # the next pair's scene alignment starts as soon as it can
                if ending is not None:
                    events = pipeline.decide("target", observed, ending.detector, also_source_of=None
                                             if starting is None else starting.detector)
                else:
                    assert starting is not None  # the first session: two sessions or more
                    events = pipeline.decide("source", observed, starting.detector)
                for event in events:
                    seen[index].count(event)
                    if isinstance(event, ObservationEvent) and is_visible(event.n_pixels):
                        visible[name].add(event.instance_id)
                    if isinstance(event, AssociationEvent):
                        taken = masks[index].setdefault(event.object_id, {})
                        taken[event.instance_id] = taken.get(event.instance_id, 0) + 1
                    if isinstance(event, TimingEvent):
                        for stage, ms in event.stage_ms.items():
                            stage_totals[name][stage] = stage_totals[name].get(stage, 0.0) + ms
                    emit(ending.relabel(event) if ending is not None else named(event, name), sinks)
                count += 1
                if on_frame is not None:
                    on_frame(name, count, total)
            frames[name], seconds[name] = count, time.perf_counter() - started
            if ending is not None:
                for event in ending.detector.finish():
                    emit(ending.relabel(event), sinks)
                transforms.append(None if ending.detector.registration is None else
                                  ending.detector.registration.transform)
        placements = compose_placements(transforms)
        maps = [pairs[0].detector.source] + [pair.detector.target for pair in pairs]
        objects = [SessionObjects({i: o.center_world for i, o in m.objects.items()},
                                  {i: o.shape_code for i, o in m.objects.items()},
                                  {i: max(taken, key=taken.__getitem__) for i, taken in session_masks.items()},
                                  {i: o.category for i, o in m.objects.items()})
                   for m, session_masks in zip(maps, masks)]
        history = link_history(names, objects, placements, [p.decisions for p in pairs],
                               LinkConfig.of(pipeline.config.detector))
        if session_events:
            emit(HistoryEvent(rows=tuple(history), names=tuple(names)), sinks)
    finally:
        ahead.close()
        for sink in sinks:
            sink.close()

    for index, (name, session_map) in enumerate(zip(names, maps)):
        if not session_map.objects:
            notes.append(f"{who(name)} has no objects: {seen[index].why_none()}")
    if session_events:
        for k, placement in enumerate(placements):
            if placement is None and (k == 0 or placements[k - 1] is not None):
                notes.append(f"{names[k]} could not be registered to {names[k - 1]} (no registration found): it and "
                             "the sessions after it have no positions in the first session's world")
    for pair in pairs:
        pair.note_registration(registration)
        pair.note_unshown()
        pair.weigh(worlds)
    return SessionsResult(names=names, paths=paths, readers=readers, frames=frames, seconds=seconds,
                          stage_totals=stage_totals, worlds=worlds, placements=placements, pairs=pairs, maps=maps,
                          visible=visible, history=history, run_notes=notes)


__all__ = ["PairResult", "SessionsResult", "run_sessions", "session_pass"]
