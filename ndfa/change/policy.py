"""When the change test's verdict on a target object becomes a decision, and which objects wait.

A decision is reported once and never retracted, and online an object's first views are often its
worst (at the edge of the image, half hidden). So an object is tested only from `min_measurements`
measurements; an "undecided" verdict waits for its evidence, and a "changed" one on fewer than
`confirm_measurements` measurements waits for more views ("unchanged" is never final, so it needs
no wait), and so does a "changed" one with a source object standing in the object's place
(`in_place`, until the end: it rests on the codes alone, which one object's unlike views split).
Waiting objects are `pending`: tested again when a new target object appears, and at
the end of the target (`final`) decided with the evidence there is. Why these rules:
`docs/detector.md`.
"""

from __future__ import annotations

from ndfa.change.config import WaitingConfig
from ndfa.change.verdict import Verdict


class DecisionPolicy:
    def __init__(self, config: WaitingConfig) -> None:
        self.config = config
        self.pending: set[int] = set()  # target objects waiting for more evidence

    def testable(self, n_measurements: int, n_sightings: int = 0) -> bool:
        """Whether an object resting on `n_measurements` measurements and `n_sightings` sightings
        (`ndfa.change.sightings`; counted only with `WaitingConfig.sightings`) is tested at all."""
        views = n_measurements + (n_sightings if self.config.sightings and n_measurements > 0 else 0)
        return views >= self.config.min_measurements

    def hold(self, object_id: int, final: bool) -> None:
        """An object too little measured to be tested waits for more; at the end it is never reported."""
        if final:
            self.pending.discard(object_id)
        else:
            self.pending.add(object_id)

    def settle(self, object_id: int, n_measurements: int, verdict: Verdict, final: bool,
               standing: int | None = None) -> Verdict:
        """The verdict to act on now. "undecided" (the object waits, and is pending) or a decision.
        `standing`: the source object standing in the object's place, if any (`in_place`)."""
        if verdict.kind == "undecided" and final:
            assert verdict.otherwise is not None  # every "undecided" verdict says what it would otherwise be
            verdict = verdict.otherwise
        if verdict.kind == "changed" and not final and self.config.in_place and standing is not None:
            verdict = Verdict("undecided", f"changed, but source object {standing} stands in its place: decided on "
                              "every view", comparisons=verdict.comparisons, otherwise=verdict, shortfall=verdict.shortfall)
        if verdict.kind == "changed" and not final and n_measurements < self.config.confirm_measurements:
            verdict = Verdict("undecided", f"changed on {n_measurements} measurements, fewer than "
                              f"{self.config.confirm_measurements}", comparisons=verdict.comparisons, otherwise=verdict)
        if verdict.kind == "undecided":
            self.pending.add(object_id)
        else:
            self.pending.discard(object_id)
        return verdict
