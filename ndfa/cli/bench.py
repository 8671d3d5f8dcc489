"""`ndfa bench ...`: speed measurements."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import app, console
from ndfa.cli.checks import at_least, at_least_one, checkpoint, non_negative, thread_count
from ndfa.eval.revision import RAW_BEFORE_REF
from ndfa.run.rate import chosen_rate


@app.command("bench")
def bench_command(
    what: str = typer.Argument("sim", help="What to time: sim (render, noise, write, read), ndf (encoding), "
                                            "detect (the target pass, and the detection step's growth) or raw "
                                            "(the whole pass over raw recordings, both sessions, per stage)."),
    frames: int = typer.Option(60, help="sim: frames to time.", callback=at_least_one),
    weights: Optional[Path] = typer.Option(None, help="ndf, detect: checkpoint to time (default: the shipped weights).",
                                           callback=checkpoint),
    source: Path = typer.Option(Path("recordings/sample/source.mcap"), help="detect, raw: source recording."),
    target: Path = typer.Option(Path("recordings/sample/target.mcap"), help="detect, raw: target recording."),
    recording: Path = typer.Option(Path("out/paper/target.mcap"), help="segment: recording with ground-truth masks."),
    step: int = typer.Option(1, help="segment: use every N-th frame.", callback=at_least_one),
    threads: int = typer.Option(1, help="detect, raw: torch's and ONNX Runtime's CPU threads (docs/speed.md).",
                                callback=thread_count),
    compare: bool = typer.Option(False, "--compare", help="detect: a before, then now, in turns (--repeat: before, "
                                                          "now, before, now ...): the code of git revision "
                                                          "--before-ref of this checkout, or without it this code "
                                                          "with --before-runtime and --before-weights, every "
                                                          "reconstruction decoded, the stages one after the other. "
                                                          "raw: the pass as git revision --before-ref ran it, "
                                                          "alternating with now."),
    before_ref: Optional[str] = typer.Option(None, help="raw, detect --compare: the git revision of this checkout "
                                                        f"whose pass is the before (raw's default: {RAW_BEFORE_REF}, "
                                                        "main on the morning of 2026-12-03; detect: none)."),
    load: bool = typer.Option(False, "--load", help="detect, raw: now once more beside one busy process (while True: pass)."),
    runtime: str = typer.Option("auto", help="detect: the NDF's runtime now: auto, onnxruntime or torch."),
    before_runtime: Optional[str] = typer.Option(None, help="detect --compare: the NDF's runtime before (default: "
                                                            "torch; with --before-ref, --runtime)."),
    before_weights: Optional[Path] = typer.Option(None, help="detect --compare: the NDF's weights before (default: "
                                                             "the shipped ones; with --before-ref, that revision's).",
                                                  callback=checkpoint),
    frame_step: int = typer.Option(1, help="detect, raw: use every N-th frame.", callback=at_least_one),
    rate: Optional[float] = typer.Option(None, help="raw: now, use frames at most this often, Hz (`ndfa detect --rate`: "
                                         "its default where not given, 0 every frame).", callback=non_negative),
    before_frame_step: Optional[int] = typer.Option(None, help="raw --compare: the before's --frame-step (default "
                                                               "--frame-step).", callback=at_least_one),
    repeat: int = typer.Option(1, help="detect, raw: run now and the before this many times, in turns; a column "
                                       "is the run of median frames/s.",
                               callback=at_least_one),
    workers: Optional[int] = typer.Option(None, help="raw: now, processes the run may use (`ndfa detect --workers`; "
                                                     "default its default).", callback=thread_count),
    overlap: bool = typer.Option(True, "--overlap/--no-overlap",
                                 help="detect: now, the stages run at the same time in threads (else one after the other)."),
    points: Optional[int] = typer.Option(None, help="detect: now, points per observation the NDF encodes (default: "
                                                    "the checkpoint's).", callback=at_least(10)),
    neighbours: Optional[int] = typer.Option(None, help="detect: now, the NDF encoder's neighbours per point "
                                                        "(default: the checkpoint's).", callback=at_least_one),
    reuse_angle: float = typer.Option(0.0, help="detect: now, observations whose view turned by less than this many "
                                                "degrees since the object was encoded take that code "
                                                "(`ndfa detect --reuse-angle`; 0: off).", min=0.0),
) -> None:
    """Time each stage of a pipeline and print milliseconds."""
    from ndfa.eval.bench import bench_detect_runs, bench_detection_scaling, bench_ndf, bench_sim
    from ndfa.ndf.runtime import RUNTIMES

    if before_ref is not None and not compare:
        raise typer.BadParameter("--before-ref names the revision --compare runs beside this code; give --compare too")
    if what == "segment":
        from ndfa.eval.segmentation import segmentation_recall
        from ndfa.io.recording import RecordingReader
        from ndfa.perception.segmentation_config import SegmentationConfig

        reader = RecordingReader(recording)
        r = segmentation_recall(reader.frames(step=step), SegmentationConfig())
        console.print(f"ndfa bench segment {recording} (every {step}. frame): {r.frames} frames; "
                      f"recovered {r.recovered}/{r.observations} = {r.recall:.1%} of the ground-truth instances with "
                      f">= 200 pixels of depth (IoU >= 0.5); {r.segments} segments, {r.spurious} matching no instance; "
                      f"{r.ms_per_frame:.1f} ms/frame ({r.cpu_ms_per_frame:.1f} ms CPU)")
        return
    if what == "raw":
        if rate is not None and frame_step > 1:
            raise typer.BadParameter("--rate and --frame-step both choose the frames: give one of them")
        _bench_raw(source, target, (before_ref or RAW_BEFORE_REF) if compare else None, load=load, repeat=repeat,
                   threads=threads, frame_step=frame_step, workers=workers, rate_hz=chosen_rate(rate, frame_step),
                   before_frame_step=before_frame_step)
        return
    if what == "detect":
        for option, value in (("--runtime", runtime), ("--before-runtime", before_runtime or runtime)):
            if value not in RUNTIMES:
                raise typer.BadParameter(f"{option} must be one of {', '.join(RUNTIMES)}, got {value!r}")
        rows = bench_detect_runs(source, target, threads=threads, compare=compare, load=load, frame_step=frame_step,
                                 runtime=runtime, weights=weights, before_runtime=before_runtime,
                                 before_weights=before_weights, overlap=overlap, repeat=repeat,
                                 n_points=points, knn=neighbours, reuse_angle_deg=reuse_angle, before_ref=before_ref)
        first = rows[0]
        table = Table(title=f"ndfa bench detect: target pass of {target} (no sinks)",
                      caption=f"{first['frames']} frames, {threads} thread(s); {first['machine']}")
        table.add_column("ms / frame")
        for row in rows:
            at = f" at {row['ref']}" if "ref" in row else ""
            table.add_column(f"{row['label']}{at} ({row['runtime']}, {Path(row['weights']).name})", justify="right")
        for stage in dict.fromkeys(stage for row in rows for stage in row["stage_ms"]):
            table.add_row(stage, *(f"{row['stage_ms'][stage]:.1f}" if stage in row["stage_ms"] else "-" for row in rows))
        table.add_row("wall time", *(f"{row['total_ms']:.1f}" for row in rows))
        table.add_row("stages", *(row["stages"] for row in rows))
        table.add_row("frames/s", *(f"{row['fps']:.1f}" for row in rows))
        table.add_row("CPU s (both passes)", *(f"{row['cpu_s']:.1f}" for row in rows))
        table.add_row("reconstructions", *(row["reconstruction"] for row in rows))
        table.add_row("points / neighbours", *(f"{row.get('points', '-')} / {row.get('neighbours', '-')}" for row in rows))
        table.add_row("codes reused within", *(f"{row['reuse_angle_deg']:g} deg" if row.get("reuse_angle_deg") else "off"
                                               for row in rows))
        table.add_row("TP / FP / FN", *("-" if row["score"] is None else "/".join(map(str, row["score"])) for row in rows))
        console.print(table)
        now = next(row for row in rows if row["label"] == "now")
        for row in rows:
            if len(row.get("fps_runs", [])) > 1:
                fps = sorted(row["fps_runs"])
                console.print(f"{row['label']}, {repeat} runs: frames/s median {row['fps']:.1f}, min {fps[0]:.1f}, "
                              f"max {fps[-1]:.1f} ({', '.join(f'{f:.1f}' for f in row['fps_runs'])})")
        if compare:
            before = rows[0]
            encoding = before["stage_ms"].get("encoding", float("nan")) / now["stage_ms"]["encoding"]
            console.print(f"speed-up of the target pass over the before: {now['fps'] / before['fps']:.2f}x "
                          f"(encoding {encoding:.2f}x)")
        if load:
            console.print(f"beside one busy process: {now['fps'] / rows[-1]['fps']:.2f}x slower")
        scaling = Table(title="detection step (tree, association, graphs) vs map size")
        scaling.add_column("objects", justify="right")
        scaling.add_column("median ms / frame (4 measurements)", justify="right")
        for row in bench_detection_scaling():
            scaling.add_row(f"{row['objects']:,}", f"{row['ms_per_frame']:.2f}")
        console.print(scaling)
        return

    if what == "sim":
        result = bench_sim(frames=frames)
        table = Table(title="ndfa bench sim (paper scene)",
                      caption=f"{result['frames']} frames {result['width']}x{result['height']}, "
                              f"{result['triangles']:,} triangles; {result['machine']}")
        rows = [("build world (once)", "world_ms"), ("render / frame", "render_ms"), ("noise / frame", "noise_ms"),
                ("write / frame", "write_ms"), ("read / frame", "read_ms"), ("render + noise + write", "total_ms_per_frame")]
    elif what == "ndf":
        result = bench_ndf(weights)
        table = Table(title="ndfa bench ndf (encode: shape code and center, then with the reconstruction grid)",
                      caption=f"{result['points']} points per observation, {result['threads']} threads; {result['machine']}")
        grid = result["grid"]
        rows = [(f"{what}: {label}", f"{prefix}{key}")
                for what, prefix in (("code + center (head)", "head_"), (f"+ grid {grid}^3", ""), ("+ grid 12^3 (detector)", "grid12_"))
                for label, key in (("one observation", "one_ms"), ("batch of 8", "batch8_ms"),
                                   ("per observation in a batch of 8", "batch8_ms_per_observation"))]
    else:
        raise typer.BadParameter(f"unknown benchmark {what!r}; expected sim, ndf, detect, raw or segment")
    table.add_column("stage")
    table.add_column("median ms", justify="right")
    for label, key in rows:
        table.add_row(label, f"{result[key]:.1f}")
    console.print(table)


def _bench_raw(source: Path, target: Path, before_ref: str | None, load: bool, repeat: int, threads: int,
               frame_step: int, workers: int | None, rate_hz: float | None = None,
               before_frame_step: int | None = None) -> None:
    """`ndfa bench raw`: the table of `ndfa.eval.bench_raw.raw_pass_runs`."""
    from ndfa.eval.bench_raw import RAW_STAGES, raw_pass_runs

    rows = raw_pass_runs(source, target, before_ref=before_ref, load=load, repeat=repeat, threads=threads,
                         frame_step=frame_step, workers=workers, rate_hz=rate_hz, before_frame_step=before_frame_step)
    now = next(row for row in rows if row["label"] == "now")
    table = Table(title=f"ndfa bench raw: {source.name} + {target.name} ({source.parent}), no sinks",
                  caption=f"{now['frames']} input frames (both sessions), {threads} thread(s), {now['workers']} process(es), "
                          f"stages {now['stages']}; "
                          f"poses {', '.join(now['poses'])}; {now['machine']}")
    table.add_column("ms / input frame (both sessions)")
    for row in rows:
        table.add_column(row["label"], justify="right")
    for stage in RAW_STAGES:
        table.add_row(stage, *(f"{row['stage_ms'][stage]:.1f}" if stage in row["stage_ms"] else "-" for row in rows))
    table.add_row("wall s", *(f"{row['wall_s']:.1f}" for row in rows))
    table.add_row("frames used (the rest skipped)", *(str(row["frames_used"]) for row in rows))
    table.add_row("frames/s (input frames / wall)", *(f"{row['fps']:.1f}" for row in rows))
    table.add_row("CPU s", *(f"{row['cpu_s']:.1f}" for row in rows))
    table.add_row(f"x real time (recorded {now['recorded_s']:.1f} s / wall)", *(f"{row['realtime']:.2f}" for row in rows))
    table.add_row("TP / FP / FN", *("-" if row["score"] is None else "/".join(map(str, row["score"])) for row in rows))
    console.print(table)
    for row in rows:
        runs = row.get("fps_runs", [])
        if len(runs) > 1:
            console.print(f"{row['label']}, {len(runs)} runs: frames/s {', '.join(f'{f:.1f}' for f in runs)}")
    if before_ref is not None:
        before = rows[0]
        if "stage_ms_target" in before:  # a revision without `raw_pass`: its `ndfa detect`
            console.print(f"before ({before_ref}, ndfa detect in a child process, its start included): its target pass "
                          + ", ".join(f"{k} {v:.1f}" for k, v in before["stage_ms_target"].items()) + " ms per target frame")
        else:
            console.print(f"before ({before_ref}): its own raw pass in a child process, timed as now's")
        console.print(f"now over before: {now['fps'] / before['fps']:.2f}x the frames/s, "
                      f"{before['cpu_s'] / now['cpu_s']:.2f}x less CPU")
    if load:
        console.print(f"beside one busy process: {now['fps'] / rows[-1]['fps']:.2f}x slower")
