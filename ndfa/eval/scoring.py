"""Object-level scoring of reported changes against a recording's ground truth (paper Sec. V-B).

A reported change names an object of one session; the object stands for the physical mug of the
mask that created it (its first instance id; in the synthetic world an instance id is a physical
mug in both sessions). A ground-truth change is a mug that was added, removed, moved, switched or
(beyond the paper) rotated: turned in place about up (docs/rotation.md).

    TP  changed mugs with at least one report (a moved mug found at its new place, at its old
        place, or both counts once)
    FN  changed mugs without a report
    FP  unchanged mugs with at least one report (object level: two reports of one mug are one FP)

The kind of a report does not enter TP/FP/FN (a switched mug reported as "added" is found, as in
the paper); it is scored on its own, per kind (`Score.kinds`): a report is of the right kind when
its mug's true change is one the kind describes (`ndfa.io.recording.ground_truth.RIGHT_KIND`:
"added" a mug that appeared at the place: added, moved or switched; "removed" one that left it;
"rotated" one turned in place), and a "moved" report also needs the same mug at both ends (its
source object's mug is its target object's): a removed mug and a different mug added elsewhere
are not a move, unless the two are of one model (`ground_truth.identical_moves`: no view tells
two mugs of one shape apart, so a report of a move is then as right as any observer can be). For the rotated mugs the score also says how many were reported as "rotated"
(`Score.rotated_found_ids` of `rotated_ids`): a turned mug reported as moved or added is a TP
but not found as turned; one reported as unchanged (no report) is an FN and not found either.

Only mugs whose change the recordings can show are scored: an added mug must be visible in the
target, a removed one in the source, and every other mug in both sessions ("visible": its mask
holds at least `VISIBLE_PIXELS` pixels with depth in at least one frame). A mug the source
never saw and the target did is "added" to any detector; a mug removed where the source never
looked cannot be missed. Nor can a change at places the other session did not show well enough
to have found a mug there (`ndfa.eval.shown`, the detector's own rule: `ndfa.change.sight`): a
mug added where the source only passed far away may as well have stood there before, and the
detector withholds such a change. A moved or switched mug shows at either of its two places. The
others are listed as unscored, not dropped silently (`Score.unshown_ids`: those for the second
reason): with the `random` preset's routes, a table can be seen only from afar in one session.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from ndfa.core.conventions import UNKNOWN_CATEGORY
from ndfa.io.recording.ground_truth import changed_instances, identical_moves, kind_is_right


@dataclass(frozen=True)
class KindReport:
    """What a report says, for the per-kind score: its kind, its mug, and a move's source-side mug."""

    kind: str
    instance_id: int
    partner_id: int | None = None  # "moved": the mug of its source object (None: unknown)
    category: str = UNKNOWN_CATEGORY  # the category the detector gave its object

    def right(self, truth: dict[int, str], identical: frozenset[tuple[int, int]] = frozenset()) -> bool:
        """Whether the kind is right for the mug's true change (`ground_truth.kind_is_right`)."""
        return kind_is_right(self.kind, self.instance_id, self.partner_id, truth, identical)


@dataclass(frozen=True)
class Score:
    tp: int
    fp: int
    fn: int
    true_positive_ids: tuple[int, ...]
    false_positive_ids: tuple[int, ...]
    false_negative_ids: tuple[int, ...]
    unscored_ids: tuple[int, ...] = ()  # mugs not visible in a session they would need to be, or unshown
    rotated_ids: tuple[int, ...] = ()        # scored mugs the ground truth turned in place
    rotated_found_ids: tuple[int, ...] = ()  # those of them with a "rotated" report
    # kind -> (reports of it on scored mugs, of the right kind): `KindReport.right`. Not part of a
    # score's equality: scores of one run at several thresholds (`ndfa.run.replay`) have no kinds.
    kinds: dict[str, tuple[int, int]] = field(default_factory=dict, compare=False)
    # true change -> (scored mugs with it, those named by a report of a right kind): the recall of
    # the kinds. A moved mug counts when a "moved" report has it at both ends, or an "added" or
    # "removed" report names it (each describes a move rightly); with `kinds` only.
    kinds_found: dict[str, tuple[int, int]] = field(default_factory=dict, compare=False)
    # true category -> (TP, FP, FN) among the scored objects of that category (`category_counts`),
    # when the ground truth holds more than one category; a report is counted by the true category
    # of the object it names, not by the category the detector gave it.
    categories: dict[str, tuple[int, int, int]] = field(default_factory=dict, compare=False)
    # (reports on scored objects that name a category, those naming the object's true one): how
    # often the NDF's category is right (none name one with a model without categories, NDF v2)
    categories_named: tuple[int, int] = field(default=(0, 0), compare=False)
    # changed mugs unscored because no place of their change was shown by the other session
    unshown_ids: tuple[int, ...] = ()

    def kind_recall(self, change: str) -> float:
        """The share of the mugs with the true `change` named by a report of a right kind (1.0 when none)."""
        mugs, found = self.kinds_found.get(change, (0, 0))
        return found / mugs if mugs else 1.0

    def kind_precision(self, kind: str) -> float:
        """The share of the reports of `kind` whose kind is right (1.0 when there are none)."""
        reports, right = self.kinds.get(kind, (0, 0))
        return right / reports if reports else 1.0

    @property
    def precision(self) -> float:
        return _ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float:
        return _ratio(self.tp, self.tp + self.fn)

    def describe_categories(self) -> str:
        """"bowl 2/0/1, mug 5/1/0": TP/FP/FN per true category ("" with one category)."""
        return ", ".join(f"{name} {tp}/{fp}/{fn}" for name, (tp, fp, fn) in sorted(self.categories.items()))

    @property
    def rotated_recall(self) -> float:
        """The share of the scored turned mugs reported as "rotated" (1.0 when there are none)."""
        return len(self.rotated_found_ids) / len(self.rotated_ids) if self.rotated_ids else 1.0

    def as_dict(self) -> dict:
        out = {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": self.precision, "recall": self.recall,
               "unscored": list(self.unscored_ids)}
        if self.unshown_ids:
            out["unshown"] = list(self.unshown_ids)
        if self.rotated_ids:  # only for scenes with turned mugs: the others' summaries stay as they were
            out["rotated"] = {"mugs": list(self.rotated_ids), "found_as_rotated": list(self.rotated_found_ids),
                              "recall": self.rotated_recall}
        if self.kinds:
            out["kinds"] = {kind: {"reports": n, "right": right, "precision": self.kind_precision(kind)}
                            for kind, (n, right) in sorted(self.kinds.items())}
        if self.categories:
            out["categories"] = {name: {"tp": tp, "fp": fp, "fn": fn, "precision": _ratio(tp, tp + fp),
                                        "recall": _ratio(tp, tp + fn)}
                                 for name, (tp, fp, fn) in sorted(self.categories.items())}
        if self.categories_named[0]:
            named, right = self.categories_named
            out["categories_named"] = {"reports": named, "right": right, "accuracy": _ratio(right, named)}
        if self.kinds_found:
            out["kinds_found"] = {change: {"mugs": n, "found": found, "recall": self.kind_recall(change)}
                                  for change, (n, found) in sorted(self.kinds_found.items())}
        return out


def _ratio(part: int, whole: int) -> float:
    return part / whole if whole else 1.0


def instance_categories(ground_truth: dict) -> dict[int, str]:
    """Instance id -> its true category (a ground truth written before the categories: "mug")."""
    return {int(o["instance_id"]): str(o.get("category", "mug")) for o in ground_truth.get("objects", [])}


def category_counts(ground_truth: dict, tp: Sequence[int], fp: Sequence[int], fn: Sequence[int]) -> dict[str, tuple[int, int, int]]:
    """True category -> (TP, FP, FN) of the scored instance ids `tp`, `fp`, `fn`; empty when the
    ground truth holds one category (the overall score is then that category's)."""
    category = instance_categories(ground_truth)
    if len(set(category.values())) < 2:
        return {}
    counts = {name: [0, 0, 0] for name in sorted(set(category.values()))}
    for column, ids in enumerate((tp, fp, fn)):
        for instance_id in ids:
            if instance_id in category:
                counts[category[instance_id]][column] += 1
    return {name: (tp_, fp_, fn_) for name, (tp_, fp_, fn_) in counts.items()}


def categories_named(ground_truth: dict, reports: Sequence[KindReport]) -> tuple[int, int]:
    """(reports that name a category, those naming their object's true category)."""
    truth = instance_categories(ground_truth)
    named = [r for r in reports if r.category != UNKNOWN_CATEGORY]
    return len(named), sum(truth.get(r.instance_id) == r.category for r in named)


def scorable_instances(ground_truth: dict, visible: dict[str, set[int]] | None,
                       shown: dict[str, set[int]] | None = None) -> set[int]:
    """Instances whose change (or lack of one) the recordings show; `visible[session]` holds the
    instance ids seen with at least `VISIBLE_PIXELS` pixels in that session (None: all), `shown[session]`
    those whose place in that session the other session showed (`ndfa.eval.shown`; None: all)."""
    needs = {"added": ("target",), "removed": ("source",)}
    ends = {"added": ("target",), "removed": ("source",), "moved": ("source", "target"), "switched": ("source", "target")}
    out = set()
    for o in ground_truth.get("objects", []):
        instance_id, change = int(o["instance_id"]), o.get("change")
        if visible is not None and not all(instance_id in visible.get(s, ()) for s in needs.get(change, ("source", "target"))):
            continue
        if shown is not None and change in ends and not any(instance_id in shown.get(s, ()) for s in ends[change]):
            continue
        out.add(instance_id)
    return out


def score(reported_instances: list[int], ground_truth: dict, visible: dict[str, set[int]] | None = None,
          rotated_instances: Sequence[int] = (), kinds: Sequence[KindReport] = (),
          shown: dict[str, set[int]] | None = None) -> Score:
    """Score the instance ids of the reported changes (one per report, repeats allowed).

    `visible`: per session, the instances visible in it; None scores every mug of the ground truth.
    `shown`: per session, the mugs whose place in it the other session showed (`ndfa.eval.shown`);
    None: every place counts as shown.
    `rotated_instances`: the instance ids of the "rotated" reports among them (`rotated_reports`).
    `kinds`: what each report says (`kind_reports`), for the per-kind score of the scored mugs.
    """
    truth = changed_instances(ground_truth)
    everything = {int(o["instance_id"]) for o in ground_truth.get("objects", [])} | set(reported_instances)
    scored = everything if visible is None and shown is None else scorable_instances(ground_truth, visible, shown)
    unshown = () if shown is None else tuple(sorted(
        set(truth) & (scorable_instances(ground_truth, visible) if visible is not None else everything) - scored))
    reported = set(reported_instances) & scored
    truth = {i: kind for i, kind in truth.items() if i in scored}
    tp = sorted(reported & truth.keys())
    fp = sorted(reported - truth.keys())
    fn = sorted(truth.keys() - reported)
    turned = sorted(i for i, kind in truth.items() if kind == "rotated")
    found = sorted(set(turned) & set(rotated_instances))
    identical = identical_moves(ground_truth)
    per_kind: dict[str, tuple[int, int]] = {}
    for report in kinds:
        if report.instance_id in scored:
            n, right = per_kind.get(report.kind, (0, 0))
            per_kind[report.kind] = (n + 1, right + int(report.right(truth, identical)))
    # A move between two mugs of one model names both rightly: the one removed and the one added.
    found_rightly = {i for report in kinds if report.right(truth, identical)
                     for i in (report.instance_id, report.partner_id) if i is not None}
    per_change: dict[str, tuple[int, int]] = {}
    for instance_id, change in truth.items() if kinds else ():
        n, right = per_change.get(change, (0, 0))
        per_change[change] = (n + 1, right + int(instance_id in found_rightly))
    return Score(len(tp), len(fp), len(fn), tuple(tp), tuple(fp), tuple(fn), tuple(sorted(everything - scored)),
                 tuple(turned), tuple(found), per_kind, per_change, category_counts(ground_truth, tp, fp, fn),
                 categories_named(ground_truth, [r for r in kinds if r.instance_id in scored]), unshown)


def kind_reports(changes: list) -> list[KindReport]:
    """What each reported change (`DecisionEvent`) says, by the mask ids of its objects."""
    return [KindReport(c.kind, c.instance_ids[0], c.partner_instance_ids[0] if c.partner_instance_ids else None,
                       c.category) for c in changes if c.instance_ids]


def rotated_reports(changes: list) -> list[int]:
    """The instance ids the "rotated" reports among `changes` (`DecisionEvent`s) stand for."""
    return [i for c in changes if c.kind == "rotated" for i in c.reported_instances]
