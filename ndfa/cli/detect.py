"""`ndfa detect`, `ndfa segment`, `ndfa eval` and `ndfa poses`: the method and its evaluation."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.change.detector import DetectorConfig
from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import at_least_one, checkpoint, in_range, output_dir, output_file, positive
from ndfa.core.errors import NdfaError
from ndfa.trajectory.kiss import OdometryConfig

# The help quotes the configs' defaults: DetectorConfig and OdometryConfig import without torch or
# scipy. The baselines' configs (scipy, open3d) are named instead of imported.
_DETECTOR, _ODOMETRY = DetectorConfig(), OdometryConfig()


@app.command("detect")
def detect_command(
    recordings: list[Path] = typer.Argument(..., help="The sessions' recordings (.mcap), in order: a source and a "
                                            "target, or more (each compared with the one before, every object "
                                            "followed over all of them: docs/sessions.md).", metavar="SESSION"),
    log: Optional[Path] = typer.Option(None, help="Write every intermediate to this Rerun file (.rrd).",
                                       callback=output_file),
    tables: Optional[Path] = typer.Option(None, help="Write the Polars tables (parquet) into this directory.",
                                          callback=output_dir),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the summary (scores, timings, changes) as JSON.",
                                            callback=output_file),
    weights: Optional[Path] = typer.Option(None, help="NDF checkpoint (default: the shipped weights).",
                                           callback=checkpoint),
    frame_step: int = typer.Option(1, help="Use every N-th frame of both recordings.", callback=at_least_one),
    no_images: bool = typer.Option(False, "--no-images", help="Leave depth/colour/mask images out of the .rrd (smaller)."),
    association_distance: Optional[float] = typer.Option(
        None, help=f"delta_d, metres (default {_DETECTOR.association.distance_m}).", callback=positive),
    shape_similarity: Optional[float] = typer.Option(
        None, help=f"delta_s (default {_DETECTOR.association.shape_similarity}; the paper: 0.9).",
        callback=in_range(ge=-1, le=1)),  # a cosine similarity
    edge_distance: Optional[float] = typer.Option(
        None, help=f"delta_e, metres (default {_DETECTOR.decision.edge_m}, the paper's).", callback=positive),
    paper_parameters: bool = typer.Option(False, "--paper-parameters", help="Start from the paper's own detector "
                                          "parameters (DetectorConfig.paper(); docs/detector.md) instead of ndfa's."),
    tree_length: Optional[float] = typer.Option(
        None, help=f"Interval length l of the object trees, metres (default {_DETECTOR.association.tree_length_m}).",
        callback=positive),
    up: str = typer.Option("auto", help="World up: auto (a synthetic recording's z, otherwise estimated from the "
                                        "support planes and levelled if tilted) | estimate (always) | z (trust "
                                        "the recording: its world is z-up)."),
    poses: str = typer.Option("auto", help="Camera poses: auto (the recording's; estimated by odometry when it has "
                                           "none) | given (never estimate) | estimate (always) | truth (a "
                                           "simulated recording's true poses: to score segmentation alone)."),
    registration: str = typer.Option("auto", help="T_rel between the sessions: auto (shape-matched object pairs, "
                                     "plus a hypothesis they verify: the shared world when both sessions' poses "
                                     "are given and their scene clouds agree, the alignment of the scene clouds "
                                     "when poses were estimated) | objects (the paper's object pairs alone) | "
                                     "shared-world (both poses are in one world: trust it) | scene (align the "
                                     "scene clouds whatever the poses)."),
    threads: Optional[int] = typer.Option(None, help="CPU threads of the NDF's runtime (ONNX Runtime: default 1; "
                                                     "torch: default one per core). 1 keeps the pass steady when "
                                                     "other jobs share the cores (docs/speed.md).",
                                          callback=at_least_one),
    runtime: str = typer.Option("auto", help="Where the NDF runs: auto (ONNX Runtime when installed, else torch) | "
                                             "onnxruntime (faster; docs/speed.md) | torch (the reference)."),
) -> None:
    """Detect added, removed and moved objects between two recordings (the paper's method), or
    between each consecutive pair of more, with every object's history over them."""
    import json
    from dataclasses import replace

    if len(recordings) < 2:
        raise typer.BadParameter(f"give two or more session recordings, got {len(recordings)}")
    if threads is not None:
        import torch

        torch.set_num_threads(threads)

    from ndfa.eval.scoring import changed_instances
    from ndfa.io.recording import RecordingReader
    from ndfa.ndf.encoder import EncoderConfig
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
    from ndfa.run.detect import RunOptions, run_detection

    association = {"distance_m": association_distance, "shape_similarity": shape_similarity, "tree_length_m": tree_length}
    defaults = DetectorConfig.paper() if paper_parameters else DetectorConfig()
    detector = replace(defaults,
                       association=replace(defaults.association, **{k: v for k, v in association.items() if v is not None}),
                       decision=replace(defaults.decision, **({} if edge_distance is None else {"edge_m": edge_distance})))
    config = PipelineConfig(detector=detector, weights=weights, encoder=EncoderConfig(runtime=runtime, threads=threads or 1))
    pipeline = ChangeDetectionPipeline(config)
    runtime = pipeline.encoder.runtime.name
    err_console.print(f"NDF runtime: {runtime}" + (f", {threads or 1} thread(s)" if runtime == "onnxruntime" else ""),
                      highlight=False)
    from ndfa.run.world import POSE_MODES, UP_MODES

    if up not in UP_MODES:
        raise typer.BadParameter(f"--up must be one of {', '.join(UP_MODES)}, got {up!r}")
    if poses not in POSE_MODES:
        raise typer.BadParameter(f"--poses must be one of {', '.join(POSE_MODES)}, got {poses!r}")
    from ndfa.run.align import REGISTRATION_MODES

    if registration not in REGISTRATION_MODES:
        raise typer.BadParameter(f"--registration must be one of {', '.join(REGISTRATION_MODES)}, got {registration!r}")
    options = RunOptions(frame_step=frame_step, up=up, poses=poses, registration=registration)
    if len(recordings) > 2:
        _detect_sessions(recordings, config, pipeline, runtime, log, tables, json_out, no_images, options)
        return
    source, target = recordings
    sinks = []
    if log is not None:
        from ndfa.log.rerun_sink import RerunSink

        sinks.append(RerunSink(log, log_images=not no_images))
    if tables is not None:
        from ndfa.log.table_sink import TableSink

        truth = RecordingReader(target).ground_truth
        sinks.append(TableSink(tables, changed_instances(truth) if truth and "objects" in truth else None))
    with progress_bar() as progress:
        result = run_detection(source, target, config, sinks, options, on_frame=bar_per_label(progress),
                               pipeline=pipeline,
                               on_world=lambda world: err_console.print(f"world {world.describe()}", highlight=False),
                               on_alignment=lambda a: err_console.print(f"registration prior: {a.describe()}",
                                                                        highlight=False))
    err_console.print(result.describe_registration(), highlight=False)
    for warning in empty_result_warnings(result):
        err_console.print(f"[yellow]warning:[/yellow] {warning}", highlight=False, soft_wrap=True)

    table = Table(title="changes")
    for column in ("kind", "session", "object", "frame", "position (source world)", "masks"):
        table.add_column(column)
    for c in result.changes:
        position = c.center_source if c.center_source is not None else c.center_world
        table.add_row(c.kind if c.angle_deg is None else f"{c.kind} {c.angle_deg:+.0f}°", c.session, str(c.object_id), str(c.frame_index),
                      " ".join(f"{v:+.2f}" for v in position), ",".join(map(str, c.instance_ids)))
    console.print(table)
    summary = result.summary() | {"ndf_runtime": runtime}
    line = f"objects: source {summary['objects_source']}, target {summary['objects_target']}; " \
           f"target pass {summary['fps']:.1f} frames/s (" + ", ".join(f"{k} {v:.1f} ms" for k, v in summary["stage_ms"].items()) + ")"
    console.print(line)
    console.print(result.describe_registration(), highlight=False)
    if result.score is not None:
        s = result.score
        console.print(f"ground truth: TP {s.tp}  FP {s.fp}  FN {s.fn}  precision {s.precision:.2f}  recall {s.recall:.2f}")
    for note in result.notes:
        console.print(f"note: {note}")
    if json_out is not None:
        from ndfa.io.atomic import atomic_path

        with atomic_path(json_out) as temporary:
            temporary.write_text(json.dumps(summary, indent=2))
    for path in (log, tables, json_out):
        if path is not None:
            console.print(f"wrote {path}")


def _detect_sessions(recordings: list[Path], config, pipeline, runtime: str, log: Optional[Path],  # noqa: ANN001
                     tables: Optional[Path], json_out: Optional[Path], no_images: bool, options) -> None:  # noqa: ANN001
    """`ndfa detect S0 S1 S2 ...`: each consecutive pair, and every object's history (`ndfa.run.sessions`)."""
    import json

    from ndfa.run.sessions import run_sessions

    sinks = []
    if log is not None:
        from ndfa.log.rerun_sink import RerunSink

        sinks.append(RerunSink(log, log_images=not no_images))
    if tables is not None:
        from ndfa.log.table_sink import TableSink

        sinks.append(TableSink(tables))  # each pair's ground truth arrives with the pair
    with progress_bar() as progress:
        result = run_sessions(recordings, config, sinks, options, on_frame=bar_per_label(progress),
                              pipeline=pipeline,
                              on_world=lambda world: err_console.print(f"world {world.describe()}", highlight=False),
                              on_alignment=lambda pair, a: err_console.print(f"pair {pair}: registration prior: "
                                                                             f"{a.describe()}", highlight=False))
    for name, path in zip(result.names, result.paths):
        console.print(f"{name}: {path} ({result.frames[name]} frames, {result.objects[name]} objects)", highlight=False)
    table = Table(title="changes between consecutive sessions (positions in the first session's world)")
    for column in ("pair", "kind", "session", "object", "frame", "position", "score", "masks"):
        table.add_column(column)
    for pair in result.pairs:
        for c in pair.changes:
            position = c.center_source if c.center_source is not None else c.center_world
            table.add_row(pair.label, c.kind, c.session, str(c.object_id), str(c.frame_index),
                          " ".join(f"{v:+.2f}" for v in position), f"{c.score:.2f}", ",".join(map(str, c.instance_ids)))
    console.print(table)
    table = Table(title="pairs")
    for column in ("pair", "registration", "changes", "TP", "FP", "FN", "precision", "recall"):
        table.add_column(column, justify="left" if column in ("pair", "registration") else "right")
    for pair in result.pairs:
        r = pair.registration
        registered = "none found" if r is None else f"{r['method']}, {r['inliers']}/{r['pairs']} inliers"
        s = pair.score
        figures = ["", "", "", "", ""] if s is None else [str(s.tp), str(s.fp), str(s.fn), f"{s.precision:.2f}",
                                                          f"{s.recall:.2f}"]
        table.add_row(pair.label, registered, str(len(pair.changes)), *figures)
    console.print(table)
    console.print(history_table(result))
    if result.history_score is not None:
        console.print(result.history_score.describe(), highlight=False)
        for d in result.history_score.disagreements:
            console.print(f"  mug {d['mug']}, object {d['object']}, session {d['session']}: {d['why']}", highlight=False)
    for note in result.notes:
        console.print(f"note: {note}")
    if json_out is not None:
        from ndfa.io.atomic import atomic_path

        with atomic_path(json_out) as temporary:
            temporary.write_text(json.dumps(result.summary() | {"ndf_runtime": runtime}, indent=2))
    for path in (log, tables, json_out):
        if path is not None:
            console.print(f"wrote {path}")


def history_table(result) -> Table:  # noqa: ANN001 (SessionsResult: imported lazily)
    """Objects down, sessions across: where each object is, and the decision that says so."""
    table = Table(title="history: each object over the sessions (here: present; -: absent; ?: not looked at)")
    table.add_column("object", justify="right")
    for name in result.names:
        table.add_column(name)
    cells: dict[int, list[str]] = {}
    for row in result.history:
        if row.present:
            text = "here" if row.decision in (None, "unchanged") else row.decision
        else:
            text = "?" if row.present is None else (row.decision if row.decision == "removed" else "-")
        if row.present and row.decision is None and row.session > 0 and row.reason:
            text += "*"  # linked by place, or not decided
        cells.setdefault(row.object, []).append(text)
    for obj, texts in cells.items():
        table.add_row(str(obj), *texts)
    table.caption = "*: no pair decision links it (linked by place and shape, or a new object); docs/sessions.md"
    return table


def empty_result_warnings(result) -> list[str]:  # noqa: ANN001 (DetectionResult: imported lazily)
    """One line each on why a run could decide nothing (it would otherwise end in a quiet empty
    table): a session without objects, and why (`run_detection` finds it out), or two sessions
    that share no objects to register them by, and what is still reported then."""
    lines = [note for note in result.notes if " has no objects: " in note]
    if not lines and result.registration is None:
        source, target = result.objects["source"], result.objects["target"]
        lines.append(f"the source and the target share no objects: none of the {target} target objects matched "
                     f"one of the {source} source objects in shape and place often enough to register the "
                     f"sessions, so no target object was tested; reported: {len(result.changes)} change(s) "
                     "decided from the source alone, and each session's objects in --tables and --json")
    return lines


@app.command("segment")
def segment_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The copy to write (.mcap).", callback=output_file),
    keep_truth: bool = typer.Option(False, "--keep-truth", help="Evaluation only: relabel each segment with the "
                                    "ground-truth instance it overlaps with IoU >= 0.5 (else 60000 + label)."),
    stride: Optional[int] = typer.Option(None, help="Sample every N-th pixel along each axis (default: width // 320).",
                                         callback=at_least_one),
) -> None:
    """Copy a recording with its instance masks replaced by the geometric segmentation (planes + DBSCAN)."""
    from ndfa.perception.segmentation_config import SegmentationConfig
    from ndfa.run.segment import segment_recording

    with progress_bar() as progress:
        task = progress.add_task("segmenting", total=None)
        count = segment_recording(recording, out, SegmentationConfig(stride=stride), keep_truth=keep_truth,
                                  on_frame=lambda done, total: progress.update(task, completed=done, total=total))
    console.print(f"wrote {out}: {count} frames segmented")


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
                                          callback=at_least_one),
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
        _eval_sweep(sweep, values, seeds, preset, step, workers, address, ray, out)
        return
    if source is None or target is None:
        raise typer.BadParameter("give SOURCE and TARGET recordings, or --sweep AXIS --values ...")
    from ndfa.eval.baselines.nn import NNConfig
    from ndfa.eval.baselines.tsdf import TSDFConfig
    from ndfa.eval.table import evaluate_methods, write_table

    nn_overrides = {"distance_m": nn_distance, "changed_fraction": nn_fraction}
    nn = NNConfig(**{k: v for k, v in nn_overrides.items() if v is not None})
    tsdf = TSDFConfig(**({} if tsdf_voxel is None else {"voxel_m": tsdf_voxel}))
    import tempfile

    with tempfile.TemporaryDirectory(prefix="ndfa-eval-") as scratch, progress_bar() as progress:
        sinks = []
        if pr_curve:  # ndfa's observations, for the replay; written only at the end, to scratch
            from ndfa.log.table_sink import TableSink

            sinks.append(TableSink(Path(scratch), flush_every=sys.maxsize))
        result = evaluate_methods(source, target, nn, tsdf, frame_step=frame_step, on_frame=bar_per_label(progress),
                                  sinks=sinks)
        observations = sinks[0].tables()["observations"] if sinks else None

    table = Table(title=f"change detection, {source.name} -> {target.name} (object level)")
    for column in ("method", "poses", "TP", "FP", "FN", "precision", "recall", "seconds"):
        table.add_column(column, justify="left" if column in ("method", "poses") else "right")
    for r in result.rows:
        table.add_row(r.method, r.poses, str(r.tp), str(r.fp), str(r.fn), f"{r.precision:.1%}", f"{r.recall:.1%}",
                      f"{r.seconds:.1f}")
    console.print(table)
    for r in result.rows:
        console.print(f"{r.method}: false positives {', '.join(map(str, r.false_positive_ids)) or '-'}; "
                      f"missed {', '.join(map(str, r.false_negative_ids)) or '-'}")
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
    import polars as pl

    from ndfa.io.atomic import write_parquet
    from ndfa.log.table_sink import HISTORY_SCHEMA, _history_row
    from ndfa.run.detect import RunOptions
    from ndfa.run.sessions import run_sessions

    with progress_bar() as progress:
        result = run_sessions(recordings, options=RunOptions(frame_step=frame_step), on_frame=bar_per_label(progress))
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
    import polars as pl

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


@app.command("poses")
def poses_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The copy with estimated poses (.mcap).", callback=output_file),
    method: str = typer.Option("estimate", help="estimate (rgbd with colour, else kiss-icp) | rgbd | kiss-icp."),
    tum_out: Optional[Path] = typer.Option(None, help="Also write the estimate as a TUM trajectory file (evo).",
                                           callback=output_file),
    voxel_size: Optional[float] = typer.Option(None, help=f"KISS-ICP map voxel, metres (default {_ODOMETRY.voxel_size_m}).",
                                               callback=positive),
    max_range: Optional[float] = typer.Option(None, help=f"Farthest point used, metres (default {_ODOMETRY.max_range_m}).",
                                              callback=positive),
    stride: Optional[int] = typer.Option(
        None, help=f"Depth averaged over STRIDE x STRIDE pixel blocks (default {_ODOMETRY.pixel_stride}).",
        callback=at_least_one),
    no_refine: bool = typer.Option(False, "--no-refine", help="KISS-ICP alone, without the point-to-plane refinement."),
) -> None:
    """Estimate camera poses from colour and depth, write a copy of the recording with them, and print ATE/RPE."""
    from ndfa.io.tum_format import write_tum
    from ndfa.trajectory import OdometryConfig, rewrite_poses

    overrides = {"voxel_size_m": voxel_size, "max_range_m": max_range, "pixel_stride": stride}
    config = OdometryConfig(**{k: v for k, v in overrides.items() if v is not None}, refine=not no_refine)
    with progress_bar() as progress:
        task = progress.add_task(method, total=None)  # rgbd counts its two passes
        report = rewrite_poses(recording, out, method, config,
                               on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    if tum_out is not None:
        write_tum(tum_out, report.timestamps, report.estimate)
    table = Table(title=f"{method} on {recording}: {report.frames} frames, against the {report.truth}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for figure, value in report.rows():
        table.add_row(figure, value)
    console.print(table)
    for path in (out, tum_out):
        if path is not None:
            console.print(f"wrote {path}")
