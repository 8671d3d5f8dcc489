"""What a run over more than two sessions tells its sinks besides the pipeline's events.

`ndfa.run.sessions` runs the two-session detector on each consecutive pair of sessions (0 -> 1,
1 -> 2, ...) and follows every object through the sessions (`ndfa.run.history`). The sinks get the
pipeline's events with `session` set to the session's name (`session_0`, ...) and every `*_source`
position in the FIRST session's world (the world every session is registered to), plus these:

    SessionStartEvent   a session's pass begins (the Rerun sink's `session` timeline)
    PairEvent           the detector events that follow belong to this pair of sessions
    HistoryEvent        every object's presence and position over the sessions, at the end
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ndfa.core.conventions import UNKNOWN_CATEGORY


@dataclass(frozen=True, kw_only=True)
class SessionStartEvent:
    """Session `index` of `names` starts its pass."""

    index: int
    names: tuple[str, ...]

    @property
    def name(self) -> str:
        return self.names[self.index]


@dataclass(frozen=True, kw_only=True)
class PairEvent:
    """The registration, graph and decision events that follow compare session `source` (index
    `index`) with session `target` (index `index + 1`). `placement`: the source session's world in
    the first session's (4, 4), None when it could not be registered. `truth`: mask instance id ->
    the ground-truth change between the two sessions, when the recordings carry it;
    `identical_moves`: its (removed, added) mugs of one model (`ndfa.io.recording.ground_truth`)."""

    index: int
    source: str
    target: str
    placement: np.ndarray | None = None
    truth: dict[int, str] | None = None
    identical_moves: frozenset[tuple[int, int]] = frozenset()

    @property
    def label(self) -> str:
        return f"{self.index}-{self.index + 1}"


@dataclass(frozen=True, kw_only=True)
class HistoryRow:
    """One object in one session (`ndfa.run.history`).

    object: the history's object id, stable over the sessions: one physical object as the pair
        decisions follow it (born in the first session that saw it, or that a pair called it added).
    present: True (the session has it), False (a pair decided it removed, or it was not there yet
        or any more), None (the session did not look where it stood: no pair decided about it).
    center_first: its center in the first session's world (None: absent, or the session could not
        be registered to the first).
    decision: the pair decision (session - 1 -> session) that explains this row: "unchanged",
        "moved", "added", "removed", another kind the detector reports, or None (first session,
        no decision, or nothing to decide); score: that decision's score (NaN: none).
    """

    object: int
    session: int
    session_name: str
    present: bool | None
    center_first: np.ndarray | None = None
    session_object: int | None = None        # the object's id in that session's object map
    instance_id: int | None = None           # the mask id it first took in that session (for scoring)
    decision: str | None = None
    score: float = float("nan")
    partner: int | None = None               # the previous session's object it was matched with
    reason: str = ""
    category: str = UNKNOWN_CATEGORY         # its category in that session (None-present rows: unknown)

    def as_dict(self) -> dict[str, Any]:
        center = self.center_first
        return {"object": self.object, "session": self.session, "session_name": self.session_name,
                "present": self.present,
                "center": None if center is None else [round(float(v), 4) for v in center],
                "session_object": self.session_object, "instance_id": self.instance_id,
                "decision": self.decision, "score": None if np.isnan(self.score) else round(float(self.score), 4),
                "partner": self.partner, "reason": self.reason, "category": self.category}


@dataclass(frozen=True, kw_only=True)
class HistoryEvent:
    """Every object's row in every session, in object then session order."""

    rows: tuple[HistoryRow, ...]
    names: tuple[str, ...]
