"""A many-session run's object history against the simulator's ground truth, object for object.

The ground truth (`ndfa ingest sim --sessions N`: each recording's `sessions`) places every mug
in every session, or says it is not there. The run's history (`ndfa.run.history`) has one row per
object per session. An object of the history stands for the mugs whose masks its rows took (each
row: the mask id its session's object took first; in the simulator a mask id is a physical mug in
every session). Then:

- objects: each mug that some session shows (visible as `ndfa.eval.scoring` counts it) must be
  exactly one history object, and each history object exactly one mug. Otherwise the mug is
  `missing` (no object), `split` (several objects: a link was lost), or the object `merged`
  (several mugs: a wrong link, e.g. a new mug taken for a removed one);
- rows: for each matched mug and session, present where the mug stands and the session shows it,
  and not present where the mug is not there (a mug standing where the session did not look is
  not scored); a present row must be within `POSITION_TOLERANCE_M` of the mug (horizontal
  distance of its center to the mug's axis, in the first session's world: the simulator's first
  session has no pose error, so its world is the true one).

`HistoryScore.matches` is the whole statement: every visible mug one object, every scored row right.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ndfa.core.sessions import HistoryRow

POSITION_TOLERANCE_M = 0.05  # a mug is ~8 cm across: further off is another place on the table


@dataclass
class HistoryScore:
    mugs: int                                   # mugs some session shows
    objects: int                                # history objects
    matched: int                                # mugs that are exactly one object, and it exactly them
    missing: list[int] = field(default_factory=list)             # mugs without an object
    split: dict[int, list[int]] = field(default_factory=dict)    # mug -> its objects
    merged: dict[int, list[int]] = field(default_factory=dict)   # object -> its mugs
    rows: int = 0                               # scored (mug, session) rows
    agree: int = 0
    disagreements: list[dict] = field(default_factory=list)      # {mug, object, session, truth, found, why}
    position_errors_m: list[float] = field(default_factory=list)  # present rows of matched mugs
    scored: list[dict] = field(default_factory=list)  # every scored row: {mug, object, session, truth, found, error_m, why}

    @property
    def matches(self) -> bool:
        return (self.matched == self.mugs and not (self.missing or self.split or self.merged)
                and self.agree == self.rows)

    def as_dict(self) -> dict:
        errors = self.position_errors_m
        return {"matches": self.matches, "mugs": self.mugs, "objects": self.objects, "matched": self.matched,
                "missing": self.missing, "split": {str(k): v for k, v in self.split.items()},
                "merged": {str(k): v for k, v in self.merged.items()}, "rows": self.rows, "agree": self.agree,
                "disagreements": self.disagreements,
                "position_error_mean_m": round(float(np.mean(errors)), 4) if errors else None,
                "position_error_max_m": round(float(np.max(errors)), 4) if errors else None}

    def describe(self) -> str:
        """One line."""
        verdict = "matches the ground truth object for object" if self.matches else "differs from the ground truth"
        errors = self.position_errors_m
        where = f"; position error mean {100 * np.mean(errors):.1f} cm, max {100 * np.max(errors):.1f} cm" if errors else ""
        return (f"history {verdict}: {self.matched}/{self.mugs} mugs one object each ({self.objects} objects), "
                f"{self.agree}/{self.rows} session rows right{where}")


def score_history(history: list[HistoryRow], truth: dict, visible: dict[str, set[int]],
                  tolerance_m: float = POSITION_TOLERANCE_M) -> HistoryScore:
    """Score `history` against the ground truth's `sessions` (`truth`); `visible[name]`: the mugs the
    session shows, by the run's session names in session order."""
    mugs = {int(o["instance_id"]): o["sessions"] for o in truth["objects"]}
    shown = list(visible.values())
    rows: dict[tuple[int, int], HistoryRow] = {(r.object, r.session): r for r in history}
    objects = sorted({r.object for r in history})
    takes: dict[int, set[int]] = {h: set() for h in objects}  # object -> the mugs its rows took
    for r in history:
        if r.present and r.instance_id is not None:
            takes[r.object].add(int(r.instance_id))
    seen = {i for ids in shown for i in ids} & set(mugs)
    held_by: dict[int, list[int]] = {i: [h for h in objects if i in takes[h]] for i in seen}
    result = HistoryScore(mugs=len(seen), objects=len(objects), matched=0)
    result.missing = sorted(i for i in seen if not held_by[i])
    result.split = {i: held_by[i] for i in sorted(seen) if len(held_by[i]) > 1}
    result.merged = {h: sorted(takes[h]) for h in objects if len(takes[h]) > 1}
    for mug in sorted(seen):
        if len(held_by[mug]) != 1 or len(takes[held_by[mug][0]]) != 1:
            continue
        result.matched += 1
        h = held_by[mug][0]
        for session, placement in enumerate(mugs[mug]):
            if session >= len(shown):
                break
            row = rows.get((h, session))
            found = None if row is None else row.present
            there = placement is not None
            if there and mug not in shown[session]:
                continue  # standing where this session did not look
            result.rows += 1
            why, error = "", float("nan")
            if there and found is not True:
                why = "not found present"
            elif not there and found is True:
                why = "found present, but the mug is not there"
            elif there and row is not None and row.center_first is not None:
                axis = np.asarray(placement["pose_world_object"])[:2, 3]
                error = float(np.linalg.norm(np.asarray(row.center_first)[:2] - axis))
                result.position_errors_m.append(error)
                if error > tolerance_m:
                    why = f"{100 * error:.1f} cm from the mug"
            scored = {"mug": mug, "object": h, "session": session, "truth": there, "found": found, "why": why}
            result.scored.append(scored | {"error_m": error})
            if why:
                result.disagreements.append(scored)
            else:
                result.agree += 1
    return result
