"""Precision/recall curves of ndfa and the two baselines (`ndfa eval SRC TGT --pr-curve`).

Each method reports an object when its score reaches a threshold; sweeping the threshold from
above the highest score down to the lowest trades precision for recall. The scores:

    ndfa   every decision's score (`DecisionEvent.score`, docs/scores.md), from one replay of the
           run's observations (`ndfa.run.replay`: no re-encoding); threshold 0.5 is the detector's
    NN     the largest share of a view's points without a source point within d
           (`NNBaseline.candidate_scores`); threshold r, the paper's 0.3
    PMT    the most conflicting iso-surface points, as a multiple of the fewest that make a
           conflict (`TSDFBaseline.candidate_scores`); threshold k, PMT's own at 1

Every point is scored by `ndfa.eval.scoring.score` with the evaluation's visible sets, so each
curve passes through its method's row of the table at the default threshold. Average precision
is the step-wise sum over the curve's points, high threshold to low, of precision times the
recall gained (scikit-learn's `average_precision_score`); recall that no threshold reaches (a
change no method ever reports) adds nothing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from ndfa.core.events import CHANGE_SCORE
from ndfa.eval.scoring import score
from ndfa.io.atomic import atomic_path, write_parquet
from ndfa.run.replay import replay, reported_at

COLUMNS = ("method", "threshold", "default", "tp", "fp", "fn", "precision", "recall")
COLOURS = {"NN": (31, 119, 180), "PMT": (255, 127, 14), "ndfa": (44, 160, 44)}


@dataclass(frozen=True)
class PRCurves:
    """One row per method and threshold (`COLUMNS`), high threshold first; AP per method."""

    table: pl.DataFrame
    average_precision: dict[str, float]
    notes: list[str] = field(default_factory=list)


def sweep(method: str, reported_at: Callable[[float], list[int]], thresholds: list[float], default: float,
          truth: dict, visible: dict[str, set[int]]) -> pl.DataFrame:
    """Score the instances `reported_at(threshold)` reports at each threshold (and at `default`,
    the method's own), high to low."""
    rows = []
    for threshold in sorted(set(thresholds) | {default}, reverse=True):
        s = score(reported_at(threshold), truth, visible)
        rows.append({"method": method, "threshold": float(threshold), "default": threshold == default, "tp": s.tp,
                     "fp": s.fp, "fn": s.fn, "precision": s.precision, "recall": s.recall})
    return pl.DataFrame(rows, schema={"method": pl.String, "threshold": pl.Float64, "default": pl.Boolean,
                                      "tp": pl.Int64, "fp": pl.Int64, "fn": pl.Int64, "precision": pl.Float64,
                                      "recall": pl.Float64})


def score_sweep(method: str, scores: dict[int, float], default: float, truth: dict,
                visible: dict[str, set[int]]) -> pl.DataFrame:
    """A method that reports instance i iff scores[i] >= threshold, at each of its distinct scores."""
    thresholds = [s for s in scores.values() if np.isfinite(s)]
    return sweep(method, lambda t: [i for i, s in scores.items() if s >= t], thresholds, default, truth, visible)


def average_precision(curve: pl.DataFrame) -> float:
    """sum over the points, high threshold first, of precision x (recall - the previous recall)."""
    rows = curve.sort("threshold", descending=True)
    recall = np.r_[0.0, rows["recall"].to_numpy()]
    return float(np.sum(np.diff(recall) * rows["precision"].to_numpy()))


def pr_curves(decisions: list, baselines: dict[str, tuple[dict[int, float], float]], truth: dict,
              visible: dict[str, set[int]]) -> PRCurves:
    """ndfa's curve from its decisions (a replay's, with scores), the baselines' from their
    candidate scores and default thresholds (name -> (scores, threshold))."""
    thresholds = [float(d.score) for d in decisions if np.isfinite(d.score)]
    parts = [sweep("ndfa", lambda t: reported_at(decisions, t), thresholds, CHANGE_SCORE, truth, visible)]
    for name, (scores, default) in baselines.items():
        parts.append(score_sweep(name, scores, default, truth, visible))
    table = pl.concat(parts)
    ap = {method: average_precision(table.filter(pl.col("method") == method))
          for method in table["method"].unique(maintain_order=True)}
    return PRCurves(table, ap)


def evaluation_curves(result, observations: pl.DataFrame) -> PRCurves:
    """The curves of an `ndfa.eval.table.evaluate_methods` run: ndfa's by replaying `observations`
    (its run's observations table) with the run's registration prior, the baselines' from the
    baselines it ran. A note says when the replay's default point differs from the run's."""
    alignment = result.detection.alignment if result.detection is not None else None
    replayed = replay(observations, prior=None if alignment is None else alignment.prior())
    # A replay has no frames, so it cannot ask whether a change's place was shown (`ndfa.change.sight`):
    # the run's answers are carried over to the same decisions.
    unshown = {(d.session, d.object_id, d.kind): d.withheld for d in result.detection.pair.unshown} \
        if result.detection is not None else {}
    decisions = [dataclasses.replace(d, withheld=unshown.get((d.session, d.object_id, d.kind), d.withheld))
                 for d in replayed.decisions]
    baselines = {name: (b.candidate_scores(), b.threshold) for name, b in result.baselines.items()}
    curves = pr_curves(decisions, baselines, result.truth, result.visible)
    own = next((r for r in result.rows if r.method == "ndfa"), None)
    at_default = curves.table.filter((pl.col("method") == "ndfa") & pl.col("default")).row(0, named=True)
    if own is not None and (own.tp, own.fp, own.fn) != (at_default["tp"], at_default["fp"], at_default["fn"]):
        curves.notes.append(f"ndfa's replay at {CHANGE_SCORE} (TP {at_default['tp']} FP {at_default['fp']} "
                            f"FN {at_default['fn']}) differs from its run (TP {own.tp} FP {own.fp} FN {own.fn})")
    return curves


def write_pr_curves(curves: PRCurves, out: Path, title: str = "") -> tuple[Path, Path]:
    """DIR/pr_curve.parquet and DIR/pr_curve.png, each written to a temporary file and renamed."""
    out.mkdir(parents=True, exist_ok=True)
    parquet, png = out / "pr_curve.parquet", out / "pr_curve.png"
    write_parquet(curves.table.select(COLUMNS), parquet)
    plot_pr_curves(curves, png, title)
    return parquet, png


def plot_pr_curves(curves: PRCurves, out_png: Path, title: str = "") -> Path:
    """Precision against recall, one step line per method, a ring at its default threshold, and
    its AP in the legend. Drawn with Pillow (matplotlib is not a dependency)."""
    from PIL import Image, ImageDraw

    size, margin = 480, 60
    image = Image.new("RGB", (size + 2 * margin, size + 2 * margin + 20), "white")
    draw = ImageDraw.Draw(image)
    left, top = margin, margin + 20
    right, bottom = left + size, top + size

    def xy(recall: float, precision: float) -> tuple[float, float]:
        return left + recall * size, bottom - precision * size

    draw.text((left, 10), title or "precision / recall, object level", fill="black")
    for k in range(11):  # grid and tick labels every 0.1
        x, y = xy(k / 10, k / 10)
        draw.line([(x, top), (x, bottom)], fill=(230, 230, 230))
        draw.line([(left, y), (right, y)], fill=(230, 230, 230))
        draw.text((x - 8, bottom + 6), f"{k / 10:.1f}", fill="black")
        draw.text((left - 30, y - 6), f"{k / 10:.1f}", fill="black")
    draw.rectangle([left, top, right, bottom], outline="black")
    draw.text(((left + right) / 2 - 15, bottom + 24), "recall", fill="black")
    draw.text((8, top - 16), "precision", fill="black")
    methods = list(curves.average_precision)
    for method in reversed(methods):  # the first method (ndfa) drawn last, on top
        n = methods.index(method)
        colour = COLOURS.get(method, (100, 100, 100))
        rows = curves.table.filter(pl.col("method") == method).sort("threshold", descending=True)
        points, recall = [], 0.0
        for row in rows.iter_rows(named=True):  # a step: recall grows at the new precision
            points += [xy(recall, row["precision"]), xy(row["recall"], row["precision"])]
            recall = row["recall"]
        if len(points) > 1:
            draw.line(points, fill=colour, width=3)
        for row in rows.filter(pl.col("default")).iter_rows(named=True):
            x, y = xy(row["recall"], row["precision"])
            draw.ellipse([x - 6, y - 6, x + 6, y + 6], outline=colour, width=2)
        legend_y = bottom - 20 * (len(curves.average_precision) - n) - 8
        draw.line([(left + 12, legend_y + 6), (left + 36, legend_y + 6)], fill=colour, width=3)
        draw.text((left + 42, legend_y), f"{method}  AP {curves.average_precision[method]:.3f}", fill="black")
    with atomic_path(out_png) as temporary:
        image.save(temporary, format="PNG")
    return out_png
