"""Every object's presence and position over many sessions, linked through the pair decisions.

The detector compares two sessions; a run over N sessions compares each consecutive pair (0 -> 1,
1 -> 2, ...), and this module follows the objects through those comparisons. Each session has its
own object map (object ids 0, 1, ... of that session); a history object id names one physical object
as the decisions follow it:

- every object of the first session starts a history object;
- a target object of pair k -> k+1 decided "unchanged" or "moved" (or any other kind that names
  the source object it is, as a turn in place does) continues its partner's history object; a
  "moved" one only when their shape codes match as one object's do (`LinkConfig.moved_similarity`):
  otherwise the pair's move is a removal and a different, added object, and the history says so;
- one decided "added", or one the pair never decided (too few views, or no registration between
  the sessions), continues the object it stands on, if any: an object last seen at most
  `LinkConfig.place_m` from it (first session's world) with a matching shape code, that no decision
  took (for an undecided one, also a source object decided "removed": a removal is the want of a
  match among the tested target objects, and this one was not tested), and for an "added" one,
  that the session before did not see (the pair's word is that none of the session before's
  objects is it; it may be one that session did not look at). Otherwise it starts a new history
  object;
- a source object decided "removed" and not continued so is absent from the next session on;
- a source object that no target object continued and that was not decided removed was not looked
  at by the next session (the target's camera did not pass it): its presence there is unknown
  (None) until a later session sees it again at its place.

A target object is linked by its final decision in the pair: a change is never retracted (an object
once found changed stays changed, `ndfa.change.detector`), a later "moved" replaces its "added", and
among repeated "unchanged" tests the last names the partner. Two target objects that name the same
partner: the one with the smaller id continues it, the other starts a new object (said in its reason).

Positions are in the first session's world: session k's objects through T_{0<-k}, the composition of
the pair registrations (`placements`); None where a pair found no registration.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ndfa.change.associate import cosine_similarity
from ndfa.change.config import DetectorConfig
from ndfa.core.conventions import UNKNOWN_CATEGORY
from ndfa.core.events import DecisionEvent
from ndfa.core.geometry import transform_points
from ndfa.core.sessions import HistoryRow


@dataclass
class PairOutcome:
    """What one pair decided, reduced to what the history needs."""

    target: dict[int, DecisionEvent] = field(default_factory=dict)   # target object -> its final decision
    removed: dict[int, DecisionEvent] = field(default_factory=dict)  # source object -> its removal

    @classmethod
    def of(cls, decisions: list[DecisionEvent]) -> PairOutcome:
        outcome = cls()
        for d in decisions:
            if d.withheld is not None:  # not shown by the other session: no evidence either way
                continue
            if d.session == "source":
                if d.kind == "removed":
                    outcome.removed[d.object_id] = d
                continue
            current = outcome.target.get(d.object_id)
            if current is None or current.kind == "unchanged" or d.kind == "moved":
                outcome.target[d.object_id] = d
        return outcome


def continues(decision: DecisionEvent) -> bool:
    """Whether a target object's decision says which source object it is."""
    return decision.kind not in ("added", "removed") and decision.partner_id is not None


def compose_placements(transforms: list[np.ndarray | None]) -> list[np.ndarray | None]:
    """T_{0<-k} for every session from each pair's T_rel (target world -> source world), None after a
    pair without one."""
    placements: list[np.ndarray | None] = [np.eye(4)]
    for transform in transforms:
        before = placements[-1]
        placements.append(None if before is None or transform is None else before @ transform)
    return placements


@dataclass(frozen=True)
class LinkConfig:
    """When an object no decision links continues one by its place.

    place_m: largest distance (first session's world) between the object and the one it continues:
        the pair registrations are good to about a centimetre (`ndfa detect`'s residual), and two
        mugs on a table stand at least a mug's width (~8 cm) apart.
    shape_similarity: smallest cosine similarity of their shape codes: the detector's delta_s
        (`AssociationConfig.shape_similarity`; `LinkConfig.of` a run's detector config), not a
        threshold of its own.
    moved_similarity: smallest cosine similarity of a "moved" object's code to the removed object's
        it moved from for the history to take them as one object: the paper's delta_s
        (`DetectorConfig.paper()`), stricter than ndfa's on purpose. The detector pairs a change
        with a removal whose codes match to its delta_s, which different mug models reach too (the
        `sample` pair: median 0.64, 90th percentile 0.93 between different models; 0.89-0.99
        between views of one mug); the paper's keeps a removed mug and a different, added one
        apart (docs/sessions.md)."""

    place_m: float = 0.05
    shape_similarity: float = field(default_factory=lambda: DetectorConfig().association.shape_similarity)
    moved_similarity: float = field(default_factory=lambda: DetectorConfig.paper().association.shape_similarity)

    @classmethod
    def of(cls, detector: DetectorConfig) -> LinkConfig:
        """The linking of a run whose detector has these parameters (its delta_s)."""
        return cls(shape_similarity=detector.association.shape_similarity)


@dataclass
class SessionObjects:
    """What the history needs of one session's object map."""

    centers: dict[int, np.ndarray]                                # object id -> center, the session's world
    codes: dict[int, np.ndarray] = field(default_factory=dict)    # object id -> shape code (for linking by place)
    instances: dict[int, int] = field(default_factory=dict)       # object id -> its mask id (for scoring)
    categories: dict[int, str] = field(default_factory=dict)      # object id -> its category (`SessionObject.category`)


def link_history(names: list[str], sessions: list[SessionObjects], placements: list[np.ndarray | None],
                 decisions: list[list[DecisionEvent]], config: LinkConfig = LinkConfig()) -> list[HistoryRow]:
    """One row per history object per session (object, then session order).

    sessions[k]: session k's objects; placements[k]: T_{0<-k}; decisions[k]: every decision of pair
    k -> k+1 (sessions "source" and "target" as the detector names them)."""
    n = len(names)
    if not (len(sessions) == len(placements) == n and len(decisions) == n - 1):
        raise ValueError(f"{n} sessions need {n} object maps and placements and {n - 1} pairs' decisions")

    def first(session: int, object_id: int) -> np.ndarray | None:
        placement = placements[session]
        center = sessions[session].centers[object_id]
        return None if placement is None else transform_points(placement, np.asarray(center)[None])[0]

    # (session, session object) -> history object; per history object and session: the explaining decision
    history: dict[tuple[int, int], int] = {}
    explained: dict[tuple[int, int], tuple[DecisionEvent | None, str]] = {}
    removed_in: dict[int, int] = {}  # history object -> the session it is absent from (removed)
    born: dict[int, int] = {}        # history object -> the session it first appears in
    last_seen: dict[int, tuple[int, int]] = {}  # history object -> (session, session object) it was last seen as
    for object_id in sorted(sessions[0].centers):
        history[0, object_id] = len(born)
        last_seen[len(born)] = (0, object_id)
        born[len(born)] = 0
    for k, pair in enumerate(decisions):
        outcome = PairOutcome.of(pair)
        claimed: dict[int, int] = {}  # history object -> the target object that continues it
        moved_apart: dict[int, tuple[DecisionEvent, str]] = {}  # source history objects of moves kept apart
        unlinked: list[tuple[int, DecisionEvent | None, str]] = []
        for target_id in sorted(sessions[k + 1].centers):
            decision = outcome.target.get(target_id)
            reason = "" if decision is None else decision.reason
            if decision is not None and continues(decision) and (k, decision.partner_id) in history:
                partner = int(decision.partner_id)  # type: ignore[arg-type]  (continues: not None)
                h = history[k, partner]
                similarity = _cosine_or_one(sessions[k + 1].codes.get(target_id), sessions[k].codes.get(partner))
                if decision.kind == "moved" and similarity < config.moved_similarity:
                    # The pair's "moved" is a change and a removal whose shapes match to delta_s;
                    # views of one mug match closer than different mugs do, so this is two mugs.
                    reason = (f"{reason}; kept apart: shape similarity {similarity:.2f} to it is below "
                              f"{config.moved_similarity} (a removed object and a different, added one)")
                    moved_apart[h] = (dataclasses.replace(
                        decision, session="source", object_id=partner, kind="removed", partner_id=None,
                        reason=f"moved to target object {target_id} by the pair, but their shapes differ "
                               f"(similarity {similarity:.2f} < {config.moved_similarity}): removed"), "")
                    unlinked.append((target_id, decision, reason))
                    continue
                if h not in claimed:
                    claimed[h] = target_id
                    history[k + 1, target_id] = h
                    explained[h, k + 1] = (decision, reason)
                    continue
                reason = f"{reason}; source object {decision.partner_id} is continued by target object {claimed[h]}"
            elif decision is None:
                reason = "not decided (too few views, or no registration between the sessions)"
            unlinked.append((target_id, decision, reason))
        gone = {h for h, session in removed_in.items() if session <= k}
        for target_id, decision, reason in unlinked:
            # An undecided object may be any source object no decision claimed, also one decided
            # removed (a removal is the want of a match among the tested objects; this one was not
            # tested); an added one, by the pair's word, none of them, but it may be one the source
            # session did not see.
            candidates = [h for h in born if h not in claimed and h not in gone and h in last_seen
                          and (decision is None or last_seen[h][0] < k)]
            h = _by_place(first(k + 1, target_id), sessions[k + 1].codes.get(target_id), candidates,
                          {h: first(*last_seen[h]) for h in candidates},
                          {h: sessions[last_seen[h][0]].codes.get(last_seen[h][1]) for h in candidates}, config)
            if h is not None:
                claimed[h] = target_id
                seen_in = last_seen[h][0]
                reason = (f"{reason}; " if reason else "") + (
                    f"continues object {h} by place and shape" if seen_in == k else
                    f"continues object {h} by place and shape (last seen in {names[seen_in]})")
            else:
                h = len(born)
                born[h] = k + 1
            history[k + 1, target_id] = h
            explained[h, k + 1] = (decision, reason)
        for source_id, decision in outcome.removed.items():
            h = history.get((k, source_id), -1)
            if h >= 0 and h not in claimed:
                removed_in[h] = k + 1
                explained[h, k + 1] = (decision, decision.reason)
        for h, (decision, _) in moved_apart.items():
            if h not in claimed:
                removed_in[h] = k + 1
                explained[h, k + 1] = (decision, decision.reason)
        for target_id in sessions[k + 1].centers:
            last_seen[history[k + 1, target_id]] = (k + 1, target_id)

    where = {(session, h): object_id for (session, object_id), h in history.items()}
    rows = []
    for h in sorted(born):
        gone_from = removed_in.get(h)
        for session in range(n):
            decision, reason = explained.get((h, session), (None, ""))
            fields = {"object": h, "session": session, "session_name": names[session], "reason": reason,
                      "decision": None if decision is None else decision.kind,
                      "score": float("nan") if decision is None else float(decision.score),
                      "partner": None if decision is None or decision.kind == "removed" else decision.partner_id}
            object_id = where.get((session, h))
            if object_id is not None:
                rows.append(HistoryRow(present=True, center_first=first(session, object_id), session_object=object_id,
                                       instance_id=sessions[session].instances.get(object_id),
                                       category=sessions[session].categories.get(object_id, UNKNOWN_CATEGORY), **fields))
            elif session < born[h] or (gone_from is not None and session >= gone_from):
                rows.append(HistoryRow(present=False, **fields))
            else:
                rows.append(HistoryRow(present=None, **(fields | {"reason": reason or "not looked at"})))
    return rows


def _by_place(center: np.ndarray | None, code: np.ndarray | None, candidates: list[int],
              centers: dict[int, np.ndarray | None], codes: dict[int, np.ndarray | None],
              config: LinkConfig) -> int | None:
    """The nearest candidate within `config.place_m` whose shape matches, or None."""
    if center is None or code is None:
        return None
    best, best_distance = None, config.place_m
    for h in candidates:
        other, other_code = centers[h], codes[h]
        if other is None or other_code is None:
            continue
        distance = float(np.linalg.norm(other - center))
        if distance <= best_distance and _cosine(code, other_code) >= config.shape_similarity:
            best, best_distance = h, distance
    return best


def _cosine_or_one(a: np.ndarray | None, b: np.ndarray | None) -> float:
    """Their cosine similarity; 1 when a code is missing (nothing to say they differ)."""
    return 1.0 if a is None or b is None else _cosine(a, b)


def _cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(cosine_similarity(a, b))
