"""`ndfa detect`: the method, between two sessions or over many (each consecutive pair, and every
object's history)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.change.config import LevelsConfig
from ndfa.change.detector import DetectorConfig
from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import (
    at_least,
    at_least_one,
    checkpoint,
    in_range,
    non_negative,
    number_text,
    output_dir,
    output_file,
    positive,
    thread_count,
)
from ndfa.core.errors import OptionError
from ndfa.io.atomic import atomic_path
from ndfa.io.recording import RecordingReader
from ndfa.io.recording.ground_truth import changed_instances, identical_moves
from ndfa.perception.segmentation_config import GATES
from ndfa.run.align import REGISTRATION_MODES
from ndfa.run.rate import DEFAULT_RATE_HZ, ODOMETRY_RATE_HZ, chosen_rate, tracked_and_used
from ndfa.run.workers import WORKERS
from ndfa.run.world import POSE_MODES, UP_MODES

# The help quotes the detector's defaults: DetectorConfig imports without torch or scipy.
_DETECTOR = DetectorConfig()


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
    weights: Optional[Path] = typer.Option(None, help="NDF checkpoint, or shipped weights by name: mugs (the default) | objects (NDF v3, every category).",
                                           callback=checkpoint),
    frame_step: int = typer.Option(1, help="Use every N-th frame of each recording (the pass and, where poses are "
                                   "estimated, the odometry: the others are skipped).", callback=at_least_one),
    rate: Optional[float] = typer.Option(None, help="Use frames at most this often, Hz, by each recording's "
                                         f"timestamps (default {number_text(DEFAULT_RATE_HZ)}: every 6th frame of a "
                                         "30 Hz recording, every frame of a slower one; the others are skipped); "
                                         "where poses are estimated the odometry tracks at most "
                                         f"{number_text(ODOMETRY_RATE_HZ)} a second, these among them. 0: every "
                                         "frame, for both (docs/speed.md).",
                                         callback=non_negative),
    no_images: bool = typer.Option(False, "--no-images", help="Leave depth/colour/mask images out of the .rrd (smaller)."),
    association_distance: Optional[float] = typer.Option(
        None, help=f"delta_d, metres (default {_DETECTOR.association.distance_m}).", callback=positive),
    shape_similarity: Optional[float] = typer.Option(
        None, help=f"delta_s (default {_DETECTOR.association.shape_similarity}; the paper: 0.9).",
        callback=in_range(ge=-1, le=1)),  # a cosine similarity
    edge_distance: Optional[float] = typer.Option(
        None, help=f"delta_e, metres (default {_DETECTOR.decision.edge_m}, the paper's).", callback=positive),
    paper_parameters: bool = typer.Option(False, "--paper-parameters", help="Start from the paper's own detector "
                                          "parameters with ndfa's additions off (DetectorConfig.paper(); "
                                          "docs/detector.md) instead of ndfa's: registration by object pairs "
                                          "alone, no scene-level prior."),
    tree_length: Optional[float] = typer.Option(
        None, help=f"Interval length l of the object trees, metres (default {_DETECTOR.association.tree_length_m}).",
        callback=positive),
    tree_height: Optional[float] = typer.Option(
        None, help=f"Interval length of the height tree T_z, metres (default {_DETECTOR.levels.tree_height_m}); 0: no "
                   "T_z, the paper's two-dimensional tree (objects on shelves above one another are neighbours; "
                   "docs/shelves.md).", callback=in_range(ge=0, le=100, why="metres; 0 switches T_z off")),
    up: str = typer.Option("auto", help="World up: auto (a synthetic recording's z, otherwise estimated from the "
                                        "support planes and levelled if tilted) | estimate (always) | z (trust "
                                        "the recording: its world is z-up)."),
    poses: str = typer.Option("auto", help="Camera poses: auto (the recording's; estimated by odometry when it has "
                                           "none) | given (never estimate) | estimate (always) | truth (a "
                                           "simulated recording's true poses: to score segmentation alone)."),
    check_poses_backward: bool = typer.Option(False, "--check-poses-backward", help="Estimated poses are "
                                              "estimated again over the frames last first; the two estimates' "
                                              "disagreement joins the pose-quality figure (twice the odometry's "
                                              "time; docs/pose_quality.md)."),
    registration: str = typer.Option("auto", help="T_rel between the sessions: auto (shape-matched object pairs, "
                                     "plus a hypothesis they verify: the shared world when both sessions' poses "
                                     "are given and their scene clouds agree, the alignment of the scene clouds "
                                     "when poses were estimated) | objects (the paper's object pairs alone) | "
                                     "shared-world (both poses are in one world: trust it) | scene (align the "
                                     "scene clouds whatever the poses)."),
    threads: Optional[int] = typer.Option(None, help="CPU threads of the NDF's runtime (ONNX Runtime: default 1; "
                                                     "torch: default one per core). 1 keeps the pass steady when "
                                                     "other jobs share the cores (docs/speed.md).",
                                          callback=thread_count),
    workers: int = typer.Option(WORKERS, help="Processes the run may use: with 2 or more, the poses of the sessions "
                                              "after the first and the scene alignment run in another process ahead "
                                              "of the passes (raw recordings); 1: all in this one "
                                              "(ndfa.run.workers, docs/speed.md).", callback=thread_count),
    runtime: str = typer.Option("auto", help="Where the NDF runs: auto (ONNX Runtime when installed, else torch) | "
                                             "onnxruntime (faster; docs/speed.md) | torch (the reference)."),
    points: Optional[int] = typer.Option(None, help="Points per observation the NDF encodes (default: the "
                                                    "checkpoint's; fewer is faster, docs/speed.md).", callback=at_least(10)),
    neighbours: Optional[int] = typer.Option(None, help="The NDF encoder's neighbours per point (default: the "
                                                        "checkpoint's).", callback=at_least_one),
    reuse_angle: float = typer.Option(0.0, help="Degrees: in frames with instance masks, an observation whose view "
                                                "of an object turned by less than this since that object was last "
                                                "encoded (centroid within 1 cm) takes that code instead of being "
                                                "encoded (faster; 0: every observation encoded, as the paper; "
                                                "docs/speed.md).", min=0.0),
    gate: str = typer.Option("auto", help="Which segments of frames without masks are objects: mugs | objects (a "
                                          "rigid object of any category on its support) | auto (objects when the "
                                          "NDF names categories, else mugs; docs/segmentation.md)."),
) -> None:
    """Detect added, removed and moved objects between two recordings (the paper's method), or
    between each consecutive pair of more, with every object's history over them."""
    if len(recordings) < 2:
        raise typer.BadParameter(f"give two or more session recordings, got {len(recordings)}")
    if gate not in GATES:
        raise typer.BadParameter(f"--gate must be one of {', '.join(GATES)}, got {gate!r}")
    if rate is not None and frame_step > 1:
        raise OptionError("--rate and --frame-step both choose the frames: give one of them")
    rate_hz = chosen_rate(rate, frame_step)
    for recording in recordings:
        reader = RecordingReader(recording)
        tracked, used = (len(p) for p in tracked_and_used(reader, frame_step, rate_hz, ODOMETRY_RATE_HZ))
        frames = len(reader)
        if used == frames:
            continue
        if used < 2 <= frames:  # a session of one frame sees one view: the step then drops all the rest
            if rate_hz is not None:
                times = reader.timestamps()
                given = "" if rate is not None else "the default "
                raise OptionError(f"{given}--rate {number_text(rate_hz)} leaves 1 of the {frames} frames of {recording}: "
                                  f"its frames span {times[-1] - times[0]:.3g} s (--rate 0: every frame)")
            raise OptionError(f"--frame-step {number_text(frame_step)} leaves 1 of the {frames} frames of {recording}: "
                              f"at most {frames - 1} keeps two")
        chosen = (f"--frame-step {frame_step}" if rate_hz is None else f"--rate {number_text(rate_hz)}"
                  + ("" if rate is not None else ", the default; --rate 0 for every frame"))
        odometry = "" if reader.has_poses or tracked == used else (
            f"; its odometry tracks {tracked} (at most {number_text(ODOMETRY_RATE_HZ)} a second)")
        err_console.print(f"{recording}: {used} of its {frames} frames used ({chosen}; the others are skipped){odometry}",
                          highlight=False)
    if threads is not None:
        import torch  # lazy: torch takes seconds to import, and `ndfa --help` none

        torch.set_num_threads(threads)

    # lazy: these import torch (seconds), which `ndfa --help` and option errors need not wait for
    from ndfa.eval.runs import score_detection
    from ndfa.ndf.encoder import EncoderConfig
    from ndfa.ndf.reuse import ReuseConfig
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
    from ndfa.run.detect import RunOptions, run_detection

    association = {"distance_m": association_distance, "shape_similarity": shape_similarity, "tree_length_m": tree_length}
    defaults = DetectorConfig.paper() if paper_parameters else DetectorConfig()
    detector = replace(defaults,
                       association=replace(defaults.association, **{k: v for k, v in association.items() if v is not None}),
                       decision=replace(defaults.decision, **({} if edge_distance is None else {"edge_m": edge_distance})))
    if tree_height is not None:
        detector = replace(detector, levels=LevelsConfig(tree_height_m=tree_height or None))
    config = PipelineConfig(detector=detector, weights=weights, encoder=EncoderConfig(runtime=runtime, threads=threads or 1,
                                                                                       n_points=points, knn=neighbours),
                            reuse=ReuseConfig(angle_deg=reuse_angle), gate=gate)
    pipeline = ChangeDetectionPipeline(config)
    runtime = pipeline.encoder.runtime.name
    named = pipeline.encoder.categories
    err_console.print(f"NDF runtime: {runtime}" + (f", {threads or 1} thread(s)" if runtime == "onnxruntime" else "")
                      + f"; categories: {', '.join(named) if named else 'none (every object is of unknown category)'}"
                      + f"; segments gated as {pipeline.gate}",
                      highlight=False)
    if up not in UP_MODES:
        raise typer.BadParameter(f"--up must be one of {', '.join(UP_MODES)}, got {up!r}")
    if poses not in POSE_MODES:
        raise typer.BadParameter(f"--poses must be one of {', '.join(POSE_MODES)}, got {poses!r}")
    if registration not in REGISTRATION_MODES:
        raise typer.BadParameter(f"--registration must be one of {', '.join(REGISTRATION_MODES)}, got {registration!r}")
    if paper_parameters and registration not in ("auto", "objects"):
        raise typer.BadParameter(f"--paper-parameters registers by object pairs alone (the paper's): no "
                                 f"--registration {registration}")
    if paper_parameters:
        registration = "objects"
    options = RunOptions(frame_step=frame_step, rate_hz=rate_hz, up=up, poses=poses, registration=registration,
                         check_poses_backward=check_poses_backward, workers=workers)
    if len(recordings) > 2:
        _detect_sessions(recordings, config, pipeline, runtime, log, tables, json_out, no_images, options)
        return
    source, target = recordings
    sinks = []
    if log is not None:
        from ndfa.log.rerun_sink import RerunSink  # lazy: rerun takes about a second to import

        sinks.append(RerunSink(log, log_images=not no_images))
    if tables is not None:
        from ndfa.log.table_sink import TableSink  # lazy: polars takes a third of a second

        truth = RecordingReader(target).ground_truth
        known = truth is not None and "objects" in truth
        sinks.append(TableSink(tables, changed_instances(truth) if known else None,
                               identical_moves=identical_moves(truth) if known else frozenset()))
    with progress_bar() as progress:
        result = score_detection(run_detection(
            source, target, config, sinks, options, on_frame=bar_per_label(progress), pipeline=pipeline,
            on_world=say_world,
            on_alignment=lambda a: err_console.print(f"registration prior: {a.describe()}", highlight=False)))
    err_console.print(result.describe_registration(), highlight=False)
    weighed = result.pair.weighed
    if weighed is not None and weighed.verdict != "good":
        _loud(weighed.notes[0])
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
    summary = result.summary() | {"ndf_runtime": runtime, "frame_step": options.frame_step, "rate_hz": options.rate_hz,
                                  "odometry_rate_hz": options.odometry_rate_hz}
    line = f"objects: source {summary['objects_source']}, target {summary['objects_target']}; " \
           f"target pass {summary['fps']:.1f} frames/s (" + ", ".join(f"{k} {v:.1f} ms" for k, v in summary["stage_ms"].items()) + ")"
    console.print(line)
    console.print(result.describe_registration(), highlight=False)
    if result.score is not None:
        s = result.score
        console.print(f"ground truth: TP {s.tp}  FP {s.fp}  FN {s.fn}  precision {s.precision:.2f}  recall {s.recall:.2f}")
        if s.kinds:
            console.print("kinds right (reports on scored mugs): " + ", ".join(
                f"{kind} {right}/{n}" for kind, (n, right) in sorted(s.kinds.items())), highlight=False)
        if s.kinds_found:
            console.print("true changes found with a right kind: " + ", ".join(
                f"{change} {found}/{n}" for change, (n, found) in sorted(s.kinds_found.items())), highlight=False)
        if s.categories:
            console.print(f"per true category, TP/FP/FN: {s.describe_categories()}", highlight=False)
        if s.categories_named[0]:
            console.print(f"reports naming their object's true category: {s.categories_named[1]}/{s.categories_named[0]}",
                          highlight=False)
    for note in result.notes:
        console.print(f"note: {note}")
    if json_out is not None:
        with atomic_path(json_out) as temporary:
            temporary.write_text(json.dumps(summary, indent=2))
    for path in (log, tables, json_out):
        if path is not None:
            console.print(f"wrote {path}")


def _detect_sessions(recordings: list[Path], config, pipeline, runtime: str, log: Optional[Path],  # noqa: ANN001
                     tables: Optional[Path], json_out: Optional[Path], no_images: bool, options) -> None:  # noqa: ANN001
    """`ndfa detect S0 S1 S2 ...`: each consecutive pair, and every object's history (`ndfa.run.sessions`)."""
    from ndfa.eval.runs import score_sessions  # lazy: these import torch
    from ndfa.run.sessions import run_sessions


    sinks = []
    if log is not None:
        from ndfa.log.rerun_sink import RerunSink  # lazy: rerun takes about a second to import

        sinks.append(RerunSink(log, log_images=not no_images))
    if tables is not None:
        from ndfa.log.table_sink import TableSink  # lazy: polars takes a third of a second

        sinks.append(TableSink(tables))  # each pair's ground truth arrives with the pair
    with progress_bar() as progress:
        result = score_sessions(run_sessions(
            recordings, config, sinks, options, on_frame=bar_per_label(progress), pipeline=pipeline,
            on_world=say_world,
            on_alignment=lambda pair, a: err_console.print(f"pair {pair}: registration prior: {a.describe()}",
                                                           highlight=False)))
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
        with atomic_path(json_out) as temporary:
            temporary.write_text(json.dumps(result.summary() | {"ndf_runtime": runtime}, indent=2))
    for path in (log, tables, json_out):
        if path is not None:
            console.print(f"wrote {path}")


def say_world(world) -> None:  # noqa: ANN001 (SessionWorld: imported lazily)
    """stderr: which poses and up a session runs on; first and loud when its estimated poses are not good."""
    quality = world.pose_quality
    if quality is not None and not quality.good:
        consequence = ("its changes will be withheld" if quality.verdict == "unusable"
                       else "its changes will be reported with lowered scores")
        _loud(f"{world.session}: estimated poses {quality.verdict.upper()}: {quality.describe()}; {consequence} "
              "(docs/pose_quality.md)")
    err_console.print(f"world {world.describe()}", highlight=False)


def _loud(line: str) -> None:
    err_console.print(f"[bold red]WARNING:[/bold red] {line}", highlight=False, soft_wrap=True)


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
