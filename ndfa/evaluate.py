"""Object-level scoring of reported changes against a recording's ground truth (paper Sec. V-B).

A reported change names an object of one session; the object stands for the physical mug of the
mask that created it (its first instance id; in the synthetic world an instance id is a physical
mug in both sessions). A ground-truth change is a mug that was added, removed, moved or switched.

    TP  changed mugs with at least one report (a moved mug found at its new place, at its old
        place, or both counts once)
    FN  changed mugs without a report
    FP  unchanged mugs with at least one report (object level: two reports of one mug are one FP)
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Score:
    tp: int
    fp: int
    fn: int
    true_positive_ids: tuple[int, ...]
    false_positive_ids: tuple[int, ...]
    false_negative_ids: tuple[int, ...]

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 1.0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 1.0

    def as_dict(self) -> dict:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": self.precision, "recall": self.recall}


def changed_instances(ground_truth: dict) -> dict[int, str]:
    """Instance id -> change kind, from a recording's ground-truth JSON."""
    return {int(o["instance_id"]): o["change"] for o in ground_truth.get("objects", [])
            if o.get("change") not in (None, "unchanged")}


def score(reported_instances: list[int], ground_truth: dict) -> Score:
    """Score the instance ids of the reported changes (one per report, repeats allowed)."""
    truth = changed_instances(ground_truth)
    reported = set(reported_instances)
    tp = sorted(reported & truth.keys())
    fp = sorted(reported - truth.keys())
    fn = sorted(truth.keys() - reported)
    return Score(len(tp), len(fp), len(fn), tuple(tp), tuple(fp), tuple(fn))
