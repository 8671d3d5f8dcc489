"""`ndfa eval`: the paper's Table I -- ndfa and the two baselines on the same pair of recordings.

ndfa runs as `ndfa detect` does, on the recordings' given poses (the target's may carry a
deliberate offset or drift); the baselines get the true poses and the instance masks as
ground-truth associations, as in the paper. All three are scored by `ndfa.eval.scoring.score` with
the same visible sets (an instance is visible in a session when some frame shows at least
`VISIBLE_PIXELS` of its pixels with depth in ndfa's range, ndfa's own rule). Seconds are the wall
time of each method's whole run, reading the recordings included.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from ndfa.core.conventions import depth_in_range, is_visible
from ndfa.core.progress import LabelledProgress
from ndfa.eval.baselines.common import BaselineError, run_baseline
from ndfa.eval.baselines.nn import NNBaseline, NNConfig
from ndfa.eval.baselines.tsdf import TSDFBaseline, TSDFConfig
from ndfa.eval.runs import score_detection
from ndfa.eval.scoring import kind_reports, rotated_reports, score
from ndfa.eval.shown import places_shown
from ndfa.io.atomic import atomic_path, write_parquet
from ndfa.io.recording import Frame, RecordingReader
from ndfa.perception.observations import ObservationConfig
from ndfa.pipeline import PipelineConfig
from ndfa.run.detect import RunOptions, run_detection


@dataclass(frozen=True)
class MethodRow:
    """One row of the table."""

    method: str
    poses: str                       # what the method was given: "given" (ndfa) or "true" (baselines)
    tp: int
    fp: int
    fn: int
    precision: float
    recall: float
    seconds: float
    false_positive_ids: tuple[int, ...]
    false_negative_ids: tuple[int, ...]
    reported_ids: tuple[int, ...]
    # kind -> (reports of it on scored mugs, of the right kind) (`Score.kinds`); ndfa's only: the
    # baselines say "changed", not which change
    kinds: dict[str, tuple[int, int]] = field(default_factory=dict)
    # true change -> (mugs with it, named by a report of a right kind) (`Score.kinds_found`); ndfa's only
    kinds_found: dict[str, tuple[int, int]] = field(default_factory=dict)
    # true category -> (TP, FP, FN) (`Score.categories`; empty with one category)
    categories: dict[str, tuple[int, int, int]] = field(default_factory=dict)

    def describe_categories(self) -> str:
        """"bowl 2/0/1, mug 5/1/0": TP/FP/FN per true category; "-" with one category."""
        return ", ".join(f"{name} {tp}/{fp}/{fn}" for name, (tp, fp, fn) in sorted(self.categories.items())) or "-"

    def describe_kinds(self) -> str:
        """"added 3/3, moved 4/5": right / reports per kind (the kinds' precision); "-" for a method
        without kinds."""
        return ", ".join(f"{kind} {right}/{n}" for kind, (n, right) in sorted(self.kinds.items())) or "-"

    def describe_kinds_found(self) -> str:
        """"added 3/4, switched 4/4": per true change, its mugs found with a right kind / its mugs
        (the kinds' recall); "-" for a method without kinds."""
        return ", ".join(f"{change} {found}/{n}" for change, (n, found) in sorted(self.kinds_found.items())) or "-"


@dataclass
class EvalResult:
    rows: list[MethodRow]
    visible: dict[str, set[int]]
    unscored_ids: tuple[int, ...]
    notes: list[str] = field(default_factory=list)
    truth: dict = field(default_factory=dict)          # the target's ground truth, as `score` takes it
    baselines: dict = field(default_factory=dict)      # name -> the baseline after its run (`ndfa.eval.pr_curve`)
    detection: object | None = None                   # ndfa's DetectionResult

    def frame(self) -> pl.DataFrame:
        return pl.DataFrame([{
            "method": r.method, "poses": r.poses, "tp": r.tp, "fp": r.fp, "fn": r.fn,
            "precision": r.precision, "recall": r.recall, "seconds": r.seconds,
            "false_positive_ids": list(r.false_positive_ids), "false_negative_ids": list(r.false_negative_ids),
            "reported_ids": list(r.reported_ids),
            "kinds": [{"kind": kind, "reports": n, "right": right} for kind, (n, right) in sorted(r.kinds.items())],
            "kinds_found": [{"change": change, "mugs": n, "found": found}
                            for change, (n, found) in sorted(r.kinds_found.items())],
            "categories": [{"category": name, "tp": tp, "fp": fp, "fn": fn}
                           for name, (tp, fp, fn) in sorted(r.categories.items())]}
            for r in self.rows],
            schema_overrides={"false_positive_ids": pl.List(pl.Int64), "false_negative_ids": pl.List(pl.Int64),
                              "reported_ids": pl.List(pl.Int64), "kinds": pl.List(pl.Struct(
                                  {"kind": pl.String, "reports": pl.Int64, "right": pl.Int64})),
                              "kinds_found": pl.List(pl.Struct(
                                  {"change": pl.String, "mugs": pl.Int64, "found": pl.Int64})),
                              "categories": pl.List(pl.Struct(
                                  {"category": pl.String, "tp": pl.Int64, "fp": pl.Int64, "fn": pl.Int64}))})

    def markdown(self) -> str:
        lines = ["| method | poses | TP | FP | FN | precision | recall | kinds right | kinds found | seconds "
                 "| false positives | missed |",
                 "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in self.rows:
            ids = lambda values: ", ".join(map(str, values)) or "—"  # noqa: E731
            lines.append(f"| {r.method} | {r.poses} | {r.tp} | {r.fp} | {r.fn} | {r.precision:.1%} | {r.recall:.1%} "
                         f"| {r.describe_kinds()} | {r.describe_kinds_found()} | {r.seconds:.1f} | {ids(r.false_positive_ids)} | {ids(r.false_negative_ids)} |")
        per_category = [f"- {r.method}, per true category (TP/FP/FN): {r.describe_categories()}"
                        for r in self.rows if r.categories]
        return "\n".join(lines + ([""] + per_category if per_category else [])) + "\n"


def open_for_baselines(source: Path, target: Path) -> tuple[RecordingReader, RecordingReader, dict]:
    """Both readers and the target's ground truth, or a BaselineError saying what is missing."""
    readers = []
    for name, path in (("source", source), ("target", target)):
        reader = RecordingReader(path)
        if not reader.has_instances:
            raise BaselineError(f"{path}: the {name} has no instance masks; the baselines need ground-truth "
                                "associations (masks whose ids name the same object in both sessions)")
        if len(reader) == 0:
            raise BaselineError(f"{path}: the {name} has no frames")
        readers.append(reader)
    truth = readers[1].ground_truth
    if truth is None or "objects" not in truth:
        raise BaselineError(f"{target}: the target has no ground truth (/ndfa/ground_truth with objects): "
                            "nothing to score the methods against")
    return readers[0], readers[1], truth


def visible_instances(frame: Frame, config: ObservationConfig = ObservationConfig()) -> set[int]:
    """Instances whose mask pixels with depth in range make them visible (ndfa's rule, `is_visible`)."""
    if frame.instances is None:
        return set()
    in_range = depth_in_range(frame.depth, config.min_depth_m, config.max_depth_m)
    counts = np.bincount(frame.instances[in_range].ravel())
    return {int(i) for i in np.flatnonzero(is_visible(counts)) if i > 0}


def evaluate_methods(source: Path, target: Path, nn: NNConfig = NNConfig(), tsdf: TSDFConfig = TSDFConfig(),
                     frame_step: int = 1, on_frame: LabelledProgress | None = None, sinks: list = ()) -> EvalResult:
    """Run ndfa, NN and PMT on the pair and score them alike. `on_frame(label, done, total)` follows
    each method's pass over each session, labelled "METHOD SESSION" (e.g. "NN source"); `sinks`
    hear ndfa's run (as `ndfa detect`'s)."""
    source_reader, target_reader, truth = open_for_baselines(Path(source), Path(target))
    visible: dict[str, set[int]] = {"source": set(), "target": set()}
    reported: dict[str, list[int]] = {}
    seconds: dict[str, float] = {}

    baselines = {"NN": NNBaseline(nn), "PMT": TSDFBaseline(tsdf)}
    for baseline in baselines.values():
        started = time.perf_counter()
        source_frames = _frames(source_reader, "source", baseline.name, frame_step, visible, on_frame)
        target_frames = _frames(target_reader, "target", baseline.name, frame_step, visible, on_frame)
        decisions = run_baseline(baseline, source_frames, target_frames)
        seconds[baseline.name] = time.perf_counter() - started
        reported[baseline.name] = [d.instance_id for d in decisions]

    started = time.perf_counter()
    progress = None if on_frame is None else (lambda session, done, total: on_frame(f"ndfa {session}", done, total))
    detection = score_detection(run_detection(Path(source), Path(target), PipelineConfig(), sinks=list(sinks),
                                              options=RunOptions(frame_step=frame_step), on_frame=progress))
    seconds["ndfa"] = time.perf_counter() - started
    reported["ndfa"] = [i for change in detection.changes for i in change.reported_instances]

    rows, notes, unscored = [], [], ()
    # Every method on one scope: the changes whose places the other session showed (`ndfa.eval.shown`)
    detector = detection.pair.detector
    shown = places_shown({"source": source_reader, "target": target_reader}, truth, detector.config.evidence,
                         detector.views["source"].rule)
    for method, poses in (("NN", "true"), ("PMT", "true"), ("ndfa", "given")):
        s = score(reported[method], truth, visible, kinds=kind_reports(detection.changes) if method == "ndfa" else (),
                  shown=shown)
        unscored = s.unscored_ids
        rows.append(MethodRow(method, poses, s.tp, s.fp, s.fn, s.precision, s.recall, seconds[method],
                              s.false_positive_ids, s.false_negative_ids, tuple(sorted(set(reported[method]))),
                              s.kinds, s.kinds_found, s.categories))
    turned = score(reported["ndfa"], truth, visible, rotated_reports(detection.changes), shown=shown)
    if turned.rotated_ids:
        notes.append(f"ndfa reported {len(turned.rotated_found_ids)} of the {len(turned.rotated_ids)} mugs turned in "
                     "place as rotated; TP/FP/FN count a turned mug found by any report (the baselines have no "
                     "rotated kind)")
    own = detection.score
    if own is not None and (own.tp, own.fp, own.fn) != (rows[-1].tp, rows[-1].fp, rows[-1].fn):
        notes.append(f"ndfa's own score (TP {own.tp} FP {own.fp} FN {own.fn}) differs from this table's: "
                     "its visible sets come from its observations")
    if unscored:
        notes.append(f"unscored (not visible where their change would show, or their places not shown by the "
                     f"other session): {', '.join(map(str, unscored))}")
    return EvalResult(rows, visible, unscored, notes + detection.notes, truth, baselines, detection)


def write_table(result: EvalResult, out: Path) -> tuple[Path, Path]:
    """DIR/table.parquet and DIR/table.md, each written to a temporary file and renamed."""
    out.mkdir(parents=True, exist_ok=True)
    parquet, markdown = out / "table.parquet", out / "table.md"
    write_parquet(result.frame(), parquet)
    with atomic_path(markdown) as temporary:
        temporary.write_text(result.markdown())
    return parquet, markdown


def _frames(reader: RecordingReader, session: str, method: str, step: int, visible: dict[str, set[int]],
            on_frame: LabelledProgress | None) -> Iterator[Frame]:
    """The session's frames, noting the visible instances and reporting progress on the way."""
    total = len(range(0, len(reader), step))
    for done, frame in enumerate(reader.frames(step=step), start=1):
        visible[session] |= visible_instances(frame)
        yield frame
        if on_frame is not None:
            on_frame(f"{method} {session}", done, total)

