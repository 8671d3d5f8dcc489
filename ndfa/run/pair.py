"""One pair of consecutive sessions in a pass (`ndfa.run.sessions`): its detector, what it decided,
and its events as the sinks get them (sessions named, positions in the first session's world)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.core.events import DecisionEvent, Event, GraphEvent, RegistrationEvent
from ndfa.core.geometry import transform_points
from ndfa.run.align import RegistrationMode, SceneAlignment
from ndfa.run.pose_verdict import WeighedChanges, weigh_changes
from ndfa.run.stream import change_summary, registration_summary


@dataclass
class PairResult:
    """Sessions `source` (index `index`) -> `target` (index `index + 1`): the pair's detector while
    the passes run, and what it decided. `score`: set by `ndfa.eval.runs` (a `Score` with masks,
    a `PositionScore` on segmented frames) when the target recording has ground truth."""

    index: int
    source: str
    target: str
    detector: ChangeDetector
    alignment: SceneAlignment | None = None           # the scene-level hypothesis offered to the detector
    placement: np.ndarray | None = None               # the source session's T_{0<-k}
    # The decisions, sessions "source"/"target" (`decisions`): every change, in order, and each
    # object's latest "unchanged" (an object is re-tested at every view: keeping each of those would
    # grow with the recording's length, and nothing reads the earlier ones)
    changes_decided: list[DecisionEvent] = field(default_factory=list)
    last_unchanged: dict[tuple[str, int], DecisionEvent] = field(default_factory=dict)
    registration_event: RegistrationEvent | None = None  # the last accepted: the T_rel of the last decisions
    notes: list[str] = field(default_factory=list)
    score: object | None = None
    weighed: WeighedChanges | None = None  # after the passes: the changes weighed by the sessions' pose verdicts

    @property
    def label(self) -> str:
        return f"{self.index}-{self.index + 1}"

    @property
    def registration(self) -> dict | None:
        """The accepted T_rel (target -> source session) as the summaries give it, or None."""
        return None if self.registration_event is None else registration_summary(self.registration_event)

    @property
    def decisions(self) -> list[DecisionEvent]:
        """Each object's latest "unchanged", then every other decision in order: what
        `ndfa.run.history.PairOutcome` and `reported_changes` read of all the decisions."""
        return list(self.last_unchanged.values()) + self.changes_decided

    @property
    def reported(self) -> list[DecisionEvent]:
        """The changes to report, as the detector made them (sessions "source"/"target", its worlds),
        less those the pose verdict withheld (`weigh`)."""
        return self.weighed.confident if self.weighed is not None else reported_changes(self.decisions)

    def weigh(self, worlds: dict) -> None:
        """After the passes: the changes weighed by the worse pose verdict of the pair's two sessions
        (`ndfa.run.pose_verdict`: withheld when unusable, scores lowered when doubtful), with a note."""
        self.weighed = weigh_changes(reported_changes(self.decisions),
                                     {"source": worlds[self.source], "target": worlds[self.target]})
        self.notes.extend(self.weighed.notes)

    @property
    def unshown(self) -> list[DecisionEvent]:
        """The changes the detector withheld because the other session's frames did not show their
        places, or showed something standing there that its map has no object of
        (`DecisionEvent.withheld`, `ndfa.change.sight`), as the detector made them."""
        return [d for d in self.changes_decided if d.withheld is not None]

    def note_unshown(self) -> None:
        """After the passes: a note on the changes withheld because their places were not seen empty."""
        unshown = self.unshown
        if unshown:
            self.notes.append(
                f"{len(unshown)} change(s) withheld, not reported: the other session's frames did not show their "
                "places empty (too far, hidden, never in view, or something stood there that it took no object "
                "of), so the difference is no evidence of a change: " + "; ".join(
                    f"{d.session} object {d.object_id} {d.kind}: {d.withheld}" for d in unshown))

    @property
    def changes(self) -> list[DecisionEvent]:
        """The changes to report, sessions named, source positions in the first session's world."""
        return [self.to_first(named(c, self.source if c.session == "source" else self.target)) for c in self.reported]

    def start_target(self, alignment: SceneAlignment | None, placement: np.ndarray | None) -> SceneAlignment | None:
        """Before the target pass: the scene-level hypothesis of T_rel (offered to the detector when it
        holds) and where the source session lies in the first one's world."""
        self.alignment, self.placement = alignment, placement
        prior = None if alignment is None else alignment.prior()
        if prior is not None:
            self.detector.add_registration_prior(prior)
        return alignment

    def relabel(self, event: Event) -> Event:
        """The event as the sinks get it: sessions named, source-world positions in the first session's
        world. Keeps the pair's decisions and registration on the way."""
        if isinstance(event, DecisionEvent) and event.kind == "unchanged":
            self.last_unchanged[(event.session, event.object_id)] = event
        elif isinstance(event, DecisionEvent):
            self.changes_decided.append(event)
        if isinstance(event, RegistrationEvent) and event.accepted:
            self.registration_event = event
        return self.to_first(named(event, self.source if getattr(event, "session", "target") == "source"
                                   else self.target))

    def to_first(self, event: Event) -> Event:
        """Source-world positions of `event` in the first session's world (the first pair's are)."""
        placement = self.placement
        if self.index == 0 or placement is None or not isinstance(event, (DecisionEvent, GraphEvent, RegistrationEvent)):
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

    def _summary(self, change: DecisionEvent) -> dict:
        """A change as the summaries list it: sessions named, in the first session's world."""
        return change_summary(self.to_first(named(change, self.source if change.session == "source" else self.target)))

    def note_registration(self, mode: RegistrationMode) -> None:
        """After the passes: notes on a pair without T_rel, and what could give it one."""
        detector, alignment = self.detector, self.alignment
        if detector.registration is not None or not detector.target.objects:
            return
        self.notes.append("no registration between the sessions was found: no target object was tested, "
                          "so only the source's observed objects could be reported")
        if alignment is not None and not alignment.ok:
            self.notes.append(f"the scene-level hypothesis did not hold ({alignment.describe()})")
            if alignment.method == "shared world" and mode == "auto":
                self.notes.append("the sessions' poses are given but do not share one world: --registration scene "
                                  "aligns their scene clouds instead")
        if alignment is not None and alignment.evidence is not None and not alignment.evidence.ok:
            self.notes.append(f"too few object pairs confirmed the {alignment.method}, and its own evidence is too "
                              f"weak to stand without them ({alignment.evidence.describe()}): no registration")

    def as_dict(self) -> dict:
        out = {"pair": self.label, "source": self.source, "target": self.target,
               "changes": [change_summary(c) for c in self.changes], "registration": self.registration,
               "scene_alignment": None if self.alignment is None else self.alignment.as_dict(), "notes": self.notes,
               "pose_verdict": "good" if self.weighed is None else self.weighed.verdict,
               "withheld_changes": [self._summary(c) | {"reason": c.withheld} for c in self.unshown]
               + ([] if self.weighed is None else [self._summary(c) | {"reason": self.weighed.reason}
                                                   for c in self.weighed.withheld])}
        if self.score is not None:
            out["score"] = self.score.as_dict()  # type: ignore[attr-defined]
        return out


def named(event: Event, name: str) -> Event:
    """`event` with its `session` set to the session's name (events without one as they are)."""
    if not hasattr(event, "session"):
        return event
    return dataclasses.replace(event, session=name)  # type: ignore[call-arg]


def _point(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    return transform_points(pose, np.asarray(point, dtype=float)[None])[0]
