"""`ndfa eval`: the paper's Table I (ndfa and the NN and PMT baselines), its precision/recall curves
(--pr-curve), sweeps over synthetic scenes (--sweep) and the many-session history scored (--history)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import at_least_one, in_range, output_dir, positive, thread_count
from ndfa.cli.detect import history_table
from ndfa.core.errors import NdfaError
from ndfa.eval.baselines.nn import NNConfig
from ndfa.io.atomic import outside_all_or_nothing, write_parquet


@app.command("eval")
def eval_command(
    recordings: Optional[list[Path]] = typer.Argument(
        None, help="Source and target session recordings (.mcap), with instance masks and ground truth; with "
        "--history two or more sessions of `ndfa ingest sim --sessions N`.", metavar="SOURCE TARGET"),
    out: Path = typer.Option(..., "--out", "-o", help="Directory for table.parquet and table.md (sweep: sweep.parquet, sweep_AXIS.png).",
                             callback=output_dir),
    nn_distance: Optional[float] = typer.Option(None, help="NN: d, metres (default: NNConfig.distance_m, the paper's).",
                                                callback=positive),
    nn_fraction: Optional[float] = typer.Option(None, help="NN: r, share of change points that makes a view changed "
                                                "(default: NNConfig.changed_fraction, the paper's).",
                                                callback=in_range(gt=0, le=1)),
    tsdf_voxel: Optional[float] = typer.Option(None, help="PMT: submap voxel size, metres (default: TSDFConfig.voxel_m; "
                                               "PMT's small-object default: 0.02).", callback=positive),
    frame_step: int = typer.Option(1, help="Use every N-th frame of both recordings, for all methods.",
                                   callback=at_least_one),
    sweep: Optional[str] = typer.Option(None, help="Instead of SOURCE TARGET: sweep an axis of synthetic scenes: "
                                        "drift | noise | objects | overlap."),
    values: Optional[str] = typer.Option(None, help="Sweep: comma-separated values of the axis."),
    seeds: str = typer.Option("0-4", help="Sweep: seeds, N, LO-HI or a comma list."),
    preset: str = typer.Option("sample", help="Sweep: scene preset of every cell (sample | paper | random)."),
    step: Optional[float] = typer.Option(None, help="Sweep: camera travel between frames, metres (preset's default).",
                                         callback=positive),
    workers: Optional[int] = typer.Option(None, help="Sweep: cells in parallel (default: CPU count; 1 = in process).",
                                          callback=thread_count),
    address: Optional[str] = typer.Option(None, help="Sweep: Ray cluster address (needs the ndfa cluster extra: Ray)."),
    ray: Optional[bool] = typer.Option(None, "--ray/--no-ray", help="Sweep: use Ray (default: when installed)."),
    pr_curve: bool = typer.Option(False, "--pr-curve", help="Also sweep each method's decision threshold (ndfa's "
                                  "score by replaying its observations, NN's r, PMT's conflict count): "
                                  "DIR/pr_curve.parquet, DIR/pr_curve.png and the average precision per method."),
    history: bool = typer.Option(False, "--history", help="Instead of Table I: run ndfa over the sessions given "
                                 "(two or more) and score each pair's changes and the objects' history against "
                                 "the ground truth: DIR/pairs.parquet, DIR/history.parquet, DIR/history_eval.parquet "
                                 "(docs/sessions.md)."),
) -> None:
    """The paper's Table I: ndfa (given poses) and the NN and PMT baselines (true poses, ground-truth masks).

    With --sweep: precision/recall/F1 of the three methods over an axis of synthetic scenes and seeds.
    With --history: ndfa over many sessions, its pairs and its object history scored."""
    recordings = recordings or []
    if history:
        if sweep is not None or pr_curve:
            raise typer.BadParameter("--history takes session recordings, not --sweep or --pr-curve")
        if len(recordings) < 2:
            raise typer.BadParameter(f"--history needs two or more session recordings, got {len(recordings)}")
        _eval_history(recordings, out, frame_step)
        return
    if len(recordings) > 2:
        raise typer.BadParameter(f"give SOURCE and TARGET (two recordings; more with --history), got {len(recordings)}")
    source, target = (recordings + [None, None])[:2]
    if sweep is not None:
        if pr_curve:
            raise typer.BadParameter("--pr-curve needs SOURCE TARGET, not --sweep")
        if source is not None or target is not None:
            raise typer.BadParameter("--sweep renders its own scenes: give no SOURCE TARGET")
        with outside_all_or_nothing():  # each finished cell is kept: a rerun resumes from them
            _eval_sweep(sweep, values, seeds, preset, step, workers, address, ray, out)
        return
    if source is None or target is None:
        raise typer.BadParameter("give SOURCE and TARGET recordings, or --sweep AXIS --values ...")
    # lazy: PMT's TSDF and the table import open3d (seconds)
    from ndfa.eval.baselines.tsdf import TSDFConfig
    from ndfa.eval.table import evaluate_methods, write_table

    nn_overrides = {"distance_m": nn_distance, "changed_fraction": nn_fraction}
    nn = NNConfig(**{k: v for k, v in nn_overrides.items() if v is not None})
    tsdf = TSDFConfig(**({} if tsdf_voxel is None else {"voxel_m": tsdf_voxel}))
    with tempfile.TemporaryDirectory(prefix="ndfa-eval-") as scratch, progress_bar() as progress:
        sinks = []
        if pr_curve:  # ndfa's observations, for the replay; written only at the end, to scratch
            from ndfa.log.table_sink import TableSink  # lazy: polars

            sinks.append(TableSink(Path(scratch), flush_every=sys.maxsize))
        result = evaluate_methods(source, target, nn, tsdf, frame_step=frame_step, on_frame=bar_per_label(progress),
                                  sinks=sinks)
        observations = sinks[0].tables()["observations"] if sinks else None

    table = Table(title=f"change detection, {source.name} -> {target.name} (object level)")
    for column in ("method", "poses", "TP", "FP", "FN", "precision", "recall", "kinds right", "seconds"):
        table.add_column(column, justify="left" if column in ("method", "poses", "kinds right") else "right")
    for r in result.rows:
        table.add_row(r.method, r.poses, str(r.tp), str(r.fp), str(r.fn), f"{r.precision:.1%}", f"{r.recall:.1%}",
                      r.describe_kinds(), f"{r.seconds:.1f}")
    console.print(table)
    for r in result.rows:
        console.print(f"{r.method}: false positives {', '.join(map(str, r.false_positive_ids)) or '-'}; "
                      f"missed {', '.join(map(str, r.false_negative_ids)) or '-'}")
        if r.kinds_found:  # the table's column is the kinds' precision; their recall here (and in table.md)
            console.print(f"{r.method}: kinds found (true changes found with a right kind): {r.describe_kinds_found()}")
        if r.categories:
            console.print(f"{r.method}: per true category, TP/FP/FN: {r.describe_categories()}", highlight=False)
    console.print(f"NN: d = {nn.distance_m * 1000:g} mm, r = {nn.changed_fraction:g}; "
                  f"PMT: {tsdf.voxel_m * 100:g} cm voxels; the baselines get the true poses and the masks' ids")
    for note in result.notes:
        console.print(f"note: {note}")
    for path in write_table(result, out):
        console.print(f"wrote {path}")
    if observations is not None:
        _write_curves(result, observations, out, f"{source.parent.name}/{source.name} -> "
                                                      f"{target.parent.name}/{target.name}")


def _eval_history(recordings: list[Path], out: Path, frame_step: int) -> None:
    """`ndfa eval --history`: every pair's score and the history's, printed and written."""
    # lazy: polars (a third of a second) and the session loop's torch (seconds)
    import polars as pl

    from ndfa.eval.runs import score_sessions
    from ndfa.log.table_sink import HISTORY_SCHEMA, _history_row
    from ndfa.run.detect import RunOptions
    from ndfa.run.sessions import run_sessions

    with progress_bar() as progress:
        result = score_sessions(run_sessions(recordings, options=RunOptions(frame_step=frame_step),
                                             on_frame=bar_per_label(progress)))
    if result.history_score is None:
        raise NdfaError(f"{recordings[-1]}: has no ground truth of the sessions (made by `ndfa ingest sim --sessions "
                        "N`, N > 2) to score the history against")
    rows = []
    table = Table(title=f"ndfa over {len(recordings)} sessions: each consecutive pair (object level)")
    for column in ("pair", "registration", "TP", "FP", "FN", "precision", "recall"):
        table.add_column(column, justify="left" if column in ("pair", "registration") else "right")
    for pair in result.pairs:
        s, r = pair.score, pair.registration
        inliers = None if r is None else r["inliers"]
        table.add_row(pair.label, "none found" if r is None else f"{r['inliers']}/{r['pairs']} inliers",
                      *(("", "", "", "", "") if s is None else (str(s.tp), str(s.fp), str(s.fn), f"{s.precision:.1%}",
                                                               f"{s.recall:.1%}")))
        rows.append({"pair": pair.label, "source": pair.source, "target": pair.target, "inliers": inliers,
                     "tp": None if s is None else s.tp, "fp": None if s is None else s.fp,
                     "fn": None if s is None else s.fn, "precision": None if s is None else s.precision,
                     "recall": None if s is None else s.recall})
    console.print(table)
    console.print(history_table(result))
    score = result.history_score
    console.print(score.describe(), highlight=False)
    for d in score.disagreements:
        console.print(f"  mug {d['mug']}, object {d['object']}, session {d['session']}: {d['why']}", highlight=False)
    for mug, objects in score.split.items():
        console.print(f"  mug {mug} is split over objects {', '.join(map(str, objects))}", highlight=False)
    for obj, mugs in score.merged.items():
        console.print(f"  object {obj} stands for mugs {', '.join(map(str, mugs))}", highlight=False)
    if score.missing:
        console.print(f"  mugs without an object: {', '.join(map(str, score.missing))}", highlight=False)
    for note in result.notes:
        console.print(f"note: {note}")
    written = {"pairs.parquet": pl.DataFrame(rows, infer_schema_length=None),
               "history.parquet": pl.DataFrame([_history_row(r) for r in result.history], schema=HISTORY_SCHEMA),
               "history_eval.parquet": pl.DataFrame(score.scored, schema={
                   "mug": pl.Int64, "object": pl.Int64, "session": pl.Int64, "truth": pl.Boolean, "found": pl.Boolean,
                   "why": pl.String, "error_m": pl.Float64})}
    for name, frame in written.items():
        write_parquet(frame, out / name)
        console.print(f"wrote {out / name}")


def _write_curves(result, observations, out: Path, title: str) -> None:
    """`ndfa eval --pr-curve`: the precision/recall curves, their average precision, the files."""
    import polars as pl  # lazy, as the curves' own module: polars

    from ndfa.eval.pr_curve import evaluation_curves, write_pr_curves

    curves = evaluation_curves(result, observations)
    table = Table(title="average precision (object level)")
    for column in ("method", "threshold swept", "default", "AP"):
        table.add_column(column, justify="left" if column in ("method", "threshold swept") else "right")
    swept = {"ndfa": "decision score", "NN": "r (change-point share)", "PMT": "k (x PMT's conflict count)"}
    for method, ap in curves.average_precision.items():
        default = curves.table.filter((pl.col("method") == method) & pl.col("default"))["threshold"][0]
        table.add_row(method, swept.get(method, "score"), f"{default:g}", f"{ap:.3f}")
    console.print(table)
    for note in curves.notes:
        console.print(f"note: {note}")
    for path in write_pr_curves(curves, out, f"precision / recall, {title}"):
        console.print(f"wrote {path}")


def _eval_sweep(axis: str, values: Optional[str], seeds: str, preset: str, step: Optional[float],
                workers: Optional[int], address: Optional[str], use_ray: Optional[bool], out: Path) -> None:
    """`ndfa eval --sweep`: run (or resume) the sweep, print the aggregated table, write parquet and PNG."""
    # lazy: polars and matplotlib (and Ray, when the sweep uses it)
    from ndfa.eval.plots import plot_sweep
    from ndfa.eval.sweep import aggregate, run_sweep, spec_from_text

    if values is None:
        raise typer.BadParameter("--sweep needs --values, e.g. --values 0,0.001,0.002")
    spec = spec_from_text(axis, values, seeds, preset, step)

    def on_cell(cell, error, done, total) -> None:
        state = f"failed: {error}" if error else "done"
        err_console.print(f"[{done}/{total}] {cell.axis}={cell.value} seed {cell.seed}: {state}")

    run = run_sweep(spec, out, workers=workers, address=address, use_ray=use_ray, on_cell=on_cell)
    summary = aggregate(run.table)
    table = Table(title=f"sweep over {axis} ({preset}, seeds {', '.join(map(str, spec.seeds))}): mean over seeds")
    for column in ("value", "method", "seeds", "TP", "FP", "FN", "P", "R", "F1", "F1 min-max", "s"):
        table.add_column(column, justify="left" if column in ("value", "method") else "right",
                         no_wrap=column in ("value", "F1 min-max"))
    for r in summary.iter_rows(named=True):
        table.add_row(r["value"], r["method"], str(r["seeds"]), str(r["tp"]), str(r["fp"]), str(r["fn"]),
                      f"{r['precision']:.2f}", f"{r['recall']:.2f}", f"{r['f1']:.2f}",
                      f"{r['f1_min']:.2f}-{r['f1_max']:.2f}", f"{r['seconds']:.1f}")
    table.caption = "TP/FP/FN summed over seeds; P, R, F1 mean over seeds; s: mean seconds of the method per cell"
    console.print(table)
    console.print(f"{run.computed} cells computed, {run.skipped} already done, {len(run.failed)} failed "
                  f"({run.backend}, {run.seconds:.0f} s)")
    for key, error in run.failed.items():
        console.print(f"failed: {key}: {error}")
    console.print(f"wrote {out / 'sweep.parquet'}")
    if not run.table.is_empty():
        console.print(f"wrote {plot_sweep(run.table, out / f'sweep_{axis}.png')}")
    if run.failed:
        raise typer.Exit(1)
