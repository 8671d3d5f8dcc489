"""What the poses' verdict does to the reported changes (`ndfa.trajectory.quality`).

A change is a difference between where two sessions' poses put an object; with wrong poses every
object can look changed (the untextured `paper` scene's drifting odometry: 38 reports, none true).
So the reports carry the worst verdict of the sessions whose poses were estimated:

- **good**: the changes as detected;
- **doubtful**: every change still reported, its score drawn halfway towards the 0.5 bar
  (`DOUBTFUL_SCORE_PULL`: it stays a change, but ranks below every confident one on a
  precision/recall curve), and a note says why;
- **unusable**: no change is reported as confident: each is withheld, listed with the reason.

Given poses (and true ones) are not judged here: they are the recording's word.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ndfa.core.events import CHANGE_SCORE, DecisionEvent, PoseQualityEvent
from ndfa.run.world import SessionWorld
from ndfa.trajectory.quality import DOUBTFUL, GOOD, UNUSABLE, VERDICTS

# A doubtful session's change scores are drawn this share of the way down to CHANGE_SCORE.
DOUBTFUL_SCORE_PULL = 0.5


@dataclass
class WeighedChanges:
    """The changes after the verdict: `confident` (reported), `withheld` (not reported as changes,
    with `reason`), the `verdict` they were weighed by, and the `notes` that say so."""

    confident: list[DecisionEvent]
    withheld: list[DecisionEvent] = field(default_factory=list)
    verdict: str = GOOD
    reason: str | None = None
    notes: list[str] = field(default_factory=list)


def worst_verdict(worlds: dict[str, SessionWorld]) -> tuple[str, list[str]]:
    """The worst verdict over the sessions with judged (estimated) poses, and those sessions' names."""
    judged = {name: world.pose_quality.verdict for name, world in worlds.items() if world.pose_quality is not None}
    worst = max(judged.values(), key=VERDICTS.index, default=GOOD)
    return worst, [name for name, verdict in judged.items() if verdict == worst and worst != GOOD]


def weigh_changes(changes: list[DecisionEvent], worlds: dict[str, SessionWorld]) -> WeighedChanges:
    """`changes` weighed by the worst pose verdict of `worlds` (see the module docstring)."""
    verdict, sessions = worst_verdict(worlds)
    if verdict == GOOD:
        return WeighedChanges(list(changes))
    which = " and ".join(f"the {name}'s" for name in sessions)
    figures = "; ".join(f"{name}: {worlds[name].pose_quality.describe()}" for name in sessions  # type: ignore[union-attr]
                        )
    if verdict == UNUSABLE:
        reason = f"{which} estimated poses are unusable ({figures}): a change between them cannot be told from the poses' error"
        note = (f"{len(changes)} change(s) withheld, not reported: {reason}. Record again with texture in view "
                "and slower turns, or give the poses")
        return WeighedChanges([], list(changes), verdict, reason, [note])
    assert verdict == DOUBTFUL
    reason = f"{which} estimated poses are doubtful ({figures})"
    note = (f"{reason}: the {len(changes)} change(s) are reported with their scores drawn halfway to "
            f"{CHANGE_SCORE}; check them before acting on them")
    return WeighedChanges([_lowered(change) for change in changes], [], verdict, reason, [note])


def _lowered(change: DecisionEvent) -> DecisionEvent:
    if np.isnan(change.score):
        return change
    return replace(change, score=CHANGE_SCORE + (1.0 - DOUBTFUL_SCORE_PULL) * (change.score - CHANGE_SCORE))




def pose_quality_event(world: SessionWorld) -> PoseQualityEvent:
    """The sinks' event of a session's judged poses."""
    quality = world.pose_quality
    assert quality is not None
    return PoseQualityEvent(session=world.session, verdict=quality.verdict, error_cm=quality.error_cm,
                            text=quality.describe(), figures=quality.evidence.to_dict())
