"""The `ndfa` command. Each subcommand parses its options, calls one library function and prints
a short table; any `NdfaError` becomes a one-line message and exit code 2."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from ndfa.errors import NdfaError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Robust object-level change detection in RGB-D data with Neural Descriptor Fields.")
ingest_app = typer.Typer(no_args_is_help=True, help="Turn a data source into ndfa recordings (MCAP).")
app.add_typer(ingest_app, name="ingest")
console = Console()
err_console = Console(stderr=True)


def _parse_range(text: str, what: str) -> tuple[int, int]:
    try:
        lo, _, hi = text.partition("-")
        return int(lo), int(hi or lo)
    except ValueError:
        raise typer.BadParameter(f"{what} must be N or LO-HI, got {text!r}") from None


def _pose_estimator(poses: str):
    """The importers' `--poses`: None for "given" (the input's own), KISS-ICP odometry for "kiss-icp"."""
    if poses == "given":
        return None
    if poses != "kiss-icp":
        raise NdfaError(f"--poses must be given or kiss-icp, got {poses!r}")
    from ndfa.trajectory.kiss import DepthOdometry

    return DepthOdometry().update


@ingest_app.command("sim")
def ingest_sim_command(
    out: Path = typer.Option(..., "--out", "-o", help="Output directory for source.mcap and target.mcap."),
    preset: str = typer.Option("paper", help="paper | sample | random."),
    seed: int = typer.Option(0, help="Seed of everything random in the scene."),
    mesh_dir: Optional[Path] = typer.Option(None, help="Place these OBJ/PLY/STL mug meshes instead of procedural ones."),
    mesh_up: str = typer.Option("z", help="Up axis of the --mesh-dir meshes: z or y."),
    tables: Optional[str] = typer.Option(None, help="Table grid as ROWSxCOLS, e.g. 2x4."),
    mugs_per_table: Optional[str] = typer.Option(None, help="Mugs per table in the source, N or LO-HI."),
    models: Optional[int] = typer.Option(None, help="Number of distinct procedural mug models."),
    added: Optional[int] = typer.Option(None, help="Mugs added in the target."),
    removed: Optional[int] = typer.Option(None, help="Mugs removed in the target."),
    moved: Optional[int] = typer.Option(None, help="Mugs moved in the target."),
    switched: Optional[int] = typer.Option(None, help="Mugs that switch places (an even number)."),
    source_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    target_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    step: Optional[float] = typer.Option(None, help="Camera travel between frames, metres."),
    noise: Optional[bool] = typer.Option(None, "--noise/--no-noise", help="Depth sensor noise on or off."),
    noise_scale: Optional[float] = typer.Option(None, help="Depth noise std as a multiple of the default sensor's."),
    offset: Optional[float] = typer.Option(None, help="Target pose offset: max translation per axis, metres."),
    offset_yaw: Optional[float] = typer.Option(None, help="Target pose offset: max yaw, degrees."),
    drift: Optional[float] = typer.Option(None, help="Target drift: random-walk translation step std, metres/frame."),
    drift_yaw: Optional[float] = typer.Option(None, help="Target drift: random-walk yaw step std, degrees/frame."),
) -> None:
    """Render a synthetic source/target pair of recordings with ground truth."""
    from ndfa.ingest.synthetic import check_output_dir, ingest_sim
    from ndfa.sim.noise import DepthNoise
    from ndfa.sim.presets import make_config

    config = make_config(preset, seed)
    overrides: dict = {}
    if tables is not None:
        rows, _, cols = tables.lower().partition("x")
        if not (rows.isdigit() and cols.isdigit()):
            raise typer.BadParameter(f"--tables must be ROWSxCOLS, got {tables!r}")
        overrides.update(table_rows=int(rows), table_cols=int(cols), total_mugs=None)
    if mugs_per_table is not None:
        overrides.update(mugs_per_table=_parse_range(mugs_per_table, "--mugs-per-table"), total_mugs=None)
    if models is not None:
        overrides["mug_models"] = models
    counts = {k: v for k, v in dict(added=added, removed=removed, moved=moved, switched=switched).items() if v is not None}
    if counts:
        overrides["changes"] = {**config.changes, **counts}
    if source_route is not None:
        overrides["source_route"] = source_route
    if target_route is not None:
        overrides["target_route"] = target_route
    if step is not None:
        overrides["trajectory"] = dataclasses.replace(config.trajectory, step_m=step)
    if noise is not None or noise_scale is not None:
        overrides["depth_noise"] = DepthNoise().scaled(1.0 if noise_scale is None else noise_scale)
        if noise is False:
            overrides["depth_noise"] = DepthNoise.off()
    error = {k: v for k, v in dict(offset_translation_m=offset, offset_yaw_deg=offset_yaw,
                                   drift_translation_m=drift, drift_yaw_deg=drift_yaw).items() if v is not None}
    if error:
        overrides["target_pose_error"] = dataclasses.replace(config.target_pose_error, **error)
    config = make_config(preset, seed, **overrides)

    check_output_dir(out)
    user_models = None
    if mesh_dir is not None:
        from ndfa.sim.mesh_io import load_mug_dir

        user_models = load_mug_dir(mesh_dir, up=mesh_up)

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=err_console, transient=False) as progress:
        tasks: dict[str, int] = {}

        def on_progress(session: str, done: int, total: int) -> None:
            if session not in tasks:
                tasks[session] = progress.add_task(f"rendering {session}", total=total)
            progress.update(tasks[session], completed=done)

        summaries = ingest_sim(config, out, models=user_models, on_progress=on_progress)

    table = Table(title=f"{config.preset} scene, seed {config.seed}: {config.table_rows * config.table_cols} tables -> {out}")
    for column in ("session", "frames", "mugs", "added", "removed", "moved", "switched", "size"):
        table.add_column(column, justify="left" if column == "session" else "right")
    for s in summaries:
        table.add_row(s.path.name, str(s.frames), str(s.objects),
                      *(str(s.changes.get(k, "")) for k in ("added", "removed", "moved", "switched")),
                      f"{s.size_bytes / 1e6:.1f} MB")
    console.print(table)


def _parse_intrinsics(text: Optional[str]) -> object:
    """None, a TUM preset name (fr1, fr2, fr3) or 'fx,fy,cx,cy' -> what ingest_tum takes."""
    if text is None or text.lower() in ("fr1", "fr2", "fr3"):
        return text.lower() if text else None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise NdfaError(f"--intrinsics must be fr1, fr2, fr3 or fx,fy,cx,cy, got {text!r}")
    return values


@ingest_app.command("tum")
def ingest_tum_command(
    folder: Path = typer.Argument(..., help="A TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt, rgb/, depth/)."),
    out: Path = typer.Option(..., "--out", "-o", help="The recording to write (.mcap)."),
    intrinsics: Optional[str] = typer.Option(None, help="fr1 | fr2 | fr3 | fx,fy,cx,cy (default: the folder's "
                                                        "calibration.txt, else TUM's ROS default 525,525,319.5,239.5)."),
    depth_scale: float = typer.Option(5000.0, help="Depth PNG units per metre (TUM: 5000)."),
    masks: Optional[Path] = typer.Option(None, help="Instance masks: 16-bit PNGs named as the depth PNGs, 0 = none "
                                                    "(default: the folder's masks/ if any)."),
    max_dt: float = typer.Option(0.02, help="Largest rgb-depth timestamp difference to pair them, seconds."),
    poses: str = typer.Option("given", help="given (groundtruth.txt) | kiss-icp (estimated from depth; "
                                            "groundtruth.txt, if any, is kept as the true poses)."),
    session: Optional[str] = typer.Option(None, help="Session name (default: the folder's name)."),
) -> None:
    """Import a TUM RGB-D folder into one recording, and say what was dropped and why."""
    import warnings

    from ndfa.ingest.tum import TumWarning, ingest_tum

    estimator = _pose_estimator(poses)
    camera = _parse_intrinsics(intrinsics)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TumWarning)  # listed under the table instead
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeRemainingColumn(), console=err_console, transient=True) as progress:
            task = progress.add_task(f"writing {out.name}", total=None)
            summary = ingest_tum(folder, out, intrinsics=camera, depth_scale=depth_scale,
                                 masks=masks, max_dt=max_dt, session=session, estimate_poses=estimator,
                                 on_progress=lambda done, total: progress.update(task, completed=done, total=total))

    table = Table(title=f"{folder} -> {out}", show_header=False)
    table.add_column("what")
    table.add_column("value", justify="right")
    table.add_row("session", summary.session)
    table.add_row("depth frames in depth.txt", str(summary.indexed))
    table.add_row("frames written", str(summary.written))
    for reason, count in summary.dropped.items():
        table.add_row(f"dropped: {reason}", str(count))
    table.add_row("depth without rgb (kept)", str(summary.depth_without_rgb))
    table.add_row("poses", summary.poses)
    table.add_row("intrinsics", summary.intrinsics)
    table.add_row("timestamps", summary.timestamps)
    table.add_row("instance masks", "yes" if summary.has_instances else "no")
    table.add_row("ground truth", "yes" if summary.has_ground_truth else "no")
    console.print(table)
    for message in summary.warnings:
        console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)


@ingest_app.command("bag")
def ingest_bag_command(
    bag: Path = typer.Argument(..., help="A ROS1 .bag file or a ROS2 bag directory (sqlite3 or mcap)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="The recording to write (.mcap)."),
    list_only: bool = typer.Option(False, "--list", help="List the bag's topics and the role each would get; write nothing."),
    rgb_topic: Optional[str] = typer.Option(None, help="Colour images (Image or CompressedImage)."),
    depth_topic: Optional[str] = typer.Option(None, help="Depth images (16UC1 mm, 32FC1 m, or compressedDepth)."),
    info_topic: Optional[str] = typer.Option(None, help="The depth camera's sensor_msgs/CameraInfo."),
    mask_topic: Optional[str] = typer.Option(None, help="Instance masks (mono16/16UC1, 0 = none)."),
    pose_topic: Optional[str] = typer.Option(None, help="tf, or a nav_msgs/Odometry or geometry_msgs/PoseStamped topic "
                                                        "(default: tf when the bag has it)."),
    world_frame: Optional[str] = typer.Option(None, help="tf frame of the world (default: map, odom or world)."),
    camera_frame: Optional[str] = typer.Option(None, help="tf frame of the camera (default: the depth images' frame_id)."),
    max_dt: float = typer.Option(0.02, help="Largest depth-colour (and depth-mask) stamp difference, seconds."),
    poses: str = typer.Option("given", help="given (from the bag) | kiss-icp (estimated from depth)."),
) -> None:
    """Import a ROS1 or ROS2 bag into one recording, and say what was skipped and why."""
    from ndfa.ingest.bag import ingest_bag, list_topics

    if list_only:
        topics = list_topics(bag)
        table = Table(title=str(bag))
        for column in ("topic", "type", "messages", "encoding", "role"):
            table.add_column(column, justify="right" if column == "messages" else "left")
        for topic in topics:
            table.add_row(topic.name, topic.msgtype, str(topic.count), topic.encoding or "", topic.role or "")
        console.print(table)
        return
    if out is None:
        raise typer.BadParameter("--out is required (or --list)")
    estimator = _pose_estimator(poses)

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=err_console, transient=True) as progress:
        task = progress.add_task(f"writing {out.name}", total=None)
        summary = ingest_bag(bag, out, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic,
                             mask_topic=mask_topic, pose_source=pose_topic, world_frame=world_frame,
                             camera_frame=camera_frame, max_dt=max_dt, estimate_poses=estimator,
                             on_progress=lambda done, total: progress.update(task, completed=done, total=total))

    table = Table(title=f"{bag} -> {out}", show_header=False)
    table.add_column("what")
    table.add_column("value", justify="right")
    for role, topic in summary.topics.items():
        table.add_row(f"{role} topic", topic)
    table.add_row("depth messages", str(summary.depth_messages))
    table.add_row("frames written", str(summary.frames))
    for reason, count in summary.skipped.items():
        table.add_row(f"skipped: {reason}", str(count))
    table.add_row("poses", summary.pose_source)
    table.add_row("frames", f"{summary.camera_frame} in {summary.world_frame or '-'}")
    table.add_row("instance masks", "yes" if summary.instances else "no")
    table.add_row("ground truth", "yes" if summary.ground_truth else "no")
    table.add_row("size", f"{summary.size_bytes / 1e6:.1f} MB")
    console.print(table)


export_app = typer.Typer(no_args_is_help=True, help="Write ndfa recordings out in other formats.")
app.add_typer(export_app, name="export")


@export_app.command("tum")
def export_tum_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The TUM folder to create (must not exist, or be empty)."),
    depth_scale: float = typer.Option(5000.0, help="Depth PNG units per metre (TUM: 5000)."),
) -> None:
    """Write a recording as a TUM RGB-D folder (plus calibration.txt, masks/ and ground truth)."""
    from ndfa.export.tum import export_tum

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=err_console, transient=True) as progress:
        task = progress.add_task(f"writing {out.name}", total=None)
        summary = export_tum(recording, out, depth_scale=depth_scale,
                             on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    console.print(f"wrote {summary.frames} frames ({summary.with_rgb} with colour"
                  f"{', masks' if summary.with_masks else ''}{', ground truth' if summary.with_ground_truth else ''}) "
                  f"to {summary.folder}")
    if summary.depth_clipped:
        console.print(f"[yellow]warning:[/yellow] {summary.depth_clipped} depth pixels beyond "
                      f"{65535 / depth_scale:.2f} m written as 0 (invalid)")


@export_app.command("bag")
def export_bag_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The bag to create: a .bag file, or a directory with --ros2."),
    ros2: bool = typer.Option(False, "--ros2", help="Write a ROS2 bag (directory) instead of a ROS1 .bag."),
    storage: str = typer.Option("sqlite3", help="ROS2 storage: sqlite3 | mcap."),
    compressed: bool = typer.Option(False, "--compressed", help="Colour as CompressedImage, depth as compressedDepth PNG."),
    color_format: str = typer.Option("jpeg", help="With --compressed: jpeg (lossy) | png."),
) -> None:
    """Write a recording as a ROS bag (images, CameraInfo, /tf, /tf_static, ground truth)."""
    from ndfa.export.bag import export_bag

    with Progress(TextColumn("[bold]{task.description}"), console=err_console, transient=True) as progress:
        progress.add_task(f"writing {out.name}", total=None)
        summary = export_bag(recording, out, version=2 if ros2 else 1, storage=storage, compressed=compressed,
                             color_format=color_format)
    console.print(f"wrote {summary.frames} frames to {summary.out} ({summary.size_bytes / 1e6:.1f} MB): "
                  + ", ".join(summary.topics))


@app.command("info")
def info_command(recording: Path = typer.Argument(..., help="An ndfa recording (.mcap).")) -> None:
    """Summarise a recording: source, frames, image size, poses and ground-truth changes."""
    from ndfa.recording import RecordingReader

    reader = RecordingReader(recording)
    meta = reader.meta
    table = Table(title=str(recording), show_header=False)
    table.add_column("key")
    table.add_column("value")
    for key in ("source", "session", "preset", "seed", "route", "poses"):
        if key in meta:
            table.add_row(key, str(meta[key]))
    table.add_row("frames", str(len(reader)))
    table.add_row("instance masks", "yes" if reader.has_instances else "no")
    truth = reader.ground_truth
    if truth:
        table.add_row("tables", str(len(truth.get("tables", []))))
        session = truth.get("session", meta.get("session"))
        present = [o for o in truth.get("objects", []) if o.get(session)]
        table.add_row("mugs in this session", str(len(present)))
        changes = truth.get("changes", {})
        table.add_row("changes", ", ".join(f"{k} {v}" for k, v in changes.items()))
    console.print(table)


@app.command("train")
def train_command(
    out: Path = typer.Option(Path("out/ndf"), "--out", "-o", help="Run directory: checkpoint.pt, metrics.parquet, config.json."),
    steps: int = typer.Option(8000, help="Optimizer steps."),
    train_mugs: int = typer.Option(400, help="Train-split mugs to render views of."),
    views_per_mug: int = typer.Option(24, help="Rendered views per training mug."),
    batch_mugs: int = typer.Option(16, help="Mugs per batch (two views each)."),
    alpha: float = typer.Option(0.01, help="Weight of the batch-hard shape loss (paper: 0.01)."),
    shape_margin: Optional[float] = typer.Option(None, help="Hinge margin of the shape loss (default: the paper's form)."),
    code_head: str = typer.Option("gram", help="Shape code: gram (invariants of z) or norms (the paper's |z_i|)."),
    lr: float = typer.Option(6e-4, help="Adam learning rate (paper: 6e-4)."),
    lr_final: float = typer.Option(1.0, help="Cosine-decay lr to this fraction of --lr by the last step (1: constant)."),
    init: Optional[Path] = typer.Option(None, help="Start from these weights (e.g. the shipped ones) with a fresh optimizer."),
    proxy_weight: float = typer.Option(0.0, help="Weight of the proxy identity loss on the shape codes (0: off)."),
    gram_eps: float = typer.Option(1e-10, help="Epsilon of the batch norm on the Gram invariants (see NDFConfig)."),
    seed: int = typer.Option(0, help="Seed of the views, the batches and the initial weights."),
    threads: int = typer.Option(2, help="Torch CPU threads (1 when another job shares the cores)."),
    resume: bool = typer.Option(False, help="Continue from OUT/checkpoint.pt."),
    data_dir: Optional[Path] = typer.Option(None, help="Cache of rendered views (default OUT/data)."),
    log: Optional[Path] = typer.Option(None, help="Also log the metrics to this Rerun file (.rrd)."),
) -> None:
    """Train the NDF on rendered partial views of train-split procedural mugs (CPU)."""
    from ndfa.ndf.model import NDFConfig
    from ndfa.ndf.train import TrainConfig, train

    config = TrainConfig(model=NDFConfig(code_head=code_head, gram_eps=gram_eps), proxy_weight=proxy_weight, train_mugs=train_mugs, views_per_mug=views_per_mug,
                         batch_mugs=batch_mugs, steps=steps, alpha=alpha, shape_margin=shape_margin, lr=lr, seed=seed,
                         threads=threads, lr_final_fraction=lr_final, init_weights=str(init) if init else None)
    recorder = None
    if log is not None:
        import rerun as rr

        recorder = rr.RecordingStream("ndfa_train")
        recorder.save(str(log))
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), TimeRemainingColumn(), console=err_console) as progress:
        task = progress.add_task("training", total=steps, info="rendering views")

        def on_step(step: int, total: int, losses: dict) -> None:
            progress.update(task, completed=step, info=f"loss {losses['loss']:.3f}")

        def on_epoch(row: dict) -> None:
            progress.console.print(
                f"epoch {row['epoch']:3d} step {row['step']:6d}  occ {row['train_occ']:.3f}  shape {row['train_shape']:+.3f}"
                f"  center {row['train_center']:.3f} | val acc {row['val_occ_accuracy']:.3f}"
                f"  center {row['val_center_median_mm']:.1f}/{row['val_center_p90_mm']:.1f} mm"
                f"  top1 {row['val_retrieval_top1']:.2f}  auc {row['val_auc']:.3f}  ({row['elapsed_s'] / 60:.1f} min)")
            if recorder is not None:
                import rerun as rr

                recorder.set_time("step", sequence=row["step"])
                for key, value in row.items():
                    if key not in ("epoch", "step"):
                        recorder.log(f"train/{key}", rr.Scalars(value))

        train(config, out, resume=resume, data_dir=data_dir, on_step=on_step, on_epoch=on_epoch)
    console.print(f"checkpoint and metrics in {out}")


@app.command("ndf-export")
def ndf_export_command(
    checkpoint: Path = typer.Argument(..., help="A training checkpoint (RUN/checkpoint.pt)."),
    to: Optional[Path] = typer.Option(None, help="Destination (default: the package's shipped weights)."),
) -> None:
    """Strip a training checkpoint to the weights the package ships and loads by default."""
    from ndfa.ndf.encoder import DEFAULT_WEIGHTS
    from ndfa.ndf.train import export_weights

    destination = to or DEFAULT_WEIGHTS
    export_weights(checkpoint, destination)
    console.print(f"wrote {destination} ({destination.stat().st_size / 1e6:.2f} MB)")


@app.command("ndf-eval")
def ndf_eval_command(
    weights: list[Path] = typer.Option(None, "--weights", "-w", help="Checkpoint(s) to evaluate (default: the shipped weights)."),
    out: Path = typer.Option(Path("out/ndf-eval"), "--out", "-o", help="Directory for summary.parquet and views.parquet."),
    mugs: int = typer.Option(20, help="Held-out test-split mugs."),
    views_per_mug: int = typer.Option(50, help="Partial views per mug."),
    seed: int = typer.Option(0, help="Seed of the test views."),
) -> None:
    """Model quality on unseen test-split mugs: center error, shape-code retrieval, IoU."""
    from ndfa.ndf.data import ViewConfig, generate_views
    from ndfa.ndf.evaluate import evaluate_ndf

    import polars as pl

    views = generate_views("test", list(range(mugs)), views_per_mug, seed, ViewConfig())
    rows = []
    out.mkdir(parents=True, exist_ok=True)
    for path in weights or [None]:
        summary, per_view = evaluate_ndf(path, views=views)
        name = str(path) if path is not None else "shipped"
        rows.append({"weights": name, **summary})
        per_view.with_columns(pl.lit(name).alias("weights")).write_parquet(out / f"views-{len(rows)}.parquet")
    table = Table(title=f"ndfa ndf-eval: {mugs} unseen test mugs x {views_per_mug} views")
    table.add_column("figure")
    for row in rows:
        table.add_column(Path(row["weights"]).parent.name or row["weights"], justify="right")
    for key in rows[0]:
        if key != "weights":
            table.add_row(key, *(f"{row[key]:.3f}" for row in rows))
    console.print(table)
    pl.DataFrame(rows).write_parquet(out / "summary.parquet")
    console.print(f"tables in {out}")


@app.command("detect")
def detect_command(
    source: Path = typer.Argument(..., help="Source session recording (.mcap)."),
    target: Path = typer.Argument(..., help="Target session recording (.mcap)."),
    log: Optional[Path] = typer.Option(None, help="Write every intermediate to this Rerun file (.rrd)."),
    tables: Optional[Path] = typer.Option(None, help="Write the Polars tables (parquet) into this directory."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the summary (scores, timings, changes) as JSON."),
    weights: Optional[Path] = typer.Option(None, help="NDF checkpoint (default: the shipped weights)."),
    frame_step: int = typer.Option(1, help="Use every N-th frame of both recordings."),
    no_images: bool = typer.Option(False, "--no-images", help="Leave depth/colour/mask images out of the .rrd (smaller)."),
    association_distance: Optional[float] = typer.Option(None, help="delta_d, metres (default 0.05)."),
    shape_similarity: Optional[float] = typer.Option(None, help="delta_s (default 0.7; the paper: 0.9)."),
    edge_distance: Optional[float] = typer.Option(None, help="delta_e, metres (default 0.03, the paper's)."),
    tree_length: Optional[float] = typer.Option(None, help="Interval length l of the object trees, metres (default 1.2)."),
    threads: Optional[int] = typer.Option(None, help="Torch CPU threads for the NDF (default: torch's, one per core). "
                                                     "1 when other jobs share the cores: oversubscribed, 2 threads "
                                                     "ran ~10x slower than 1."),
) -> None:
    """Detect added, removed and moved objects between two recordings (the paper's method)."""
    import json

    if threads is not None:
        import torch

        if threads < 1:
            raise typer.BadParameter(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)

    from ndfa.change.detector import DetectorConfig
    from ndfa.detect import run_detection
    from ndfa.evaluate import changed_instances
    from ndfa.pipeline import PipelineConfig
    from ndfa.recording import RecordingReader

    overrides = {"association_distance_m": association_distance, "shape_similarity": shape_similarity,
                 "edge_m": edge_distance, "tree_length_m": tree_length}
    detector = DetectorConfig(**{k: v for k, v in overrides.items() if v is not None})
    config = PipelineConfig(detector=detector, weights=weights)
    if frame_step < 1:
        raise typer.BadParameter(f"--frame-step must be >= 1, got {frame_step}")
    sinks = []
    if log is not None:
        from ndfa.log.rerun_sink import RerunSink

        sinks.append(RerunSink(log, log_images=not no_images))
    if tables is not None:
        from ndfa.log.table_sink import TableSink

        truth = RecordingReader(target).ground_truth
        sinks.append(TableSink(tables, changed_instances(truth) if truth and "objects" in truth else None))
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=err_console, transient=True) as progress:
        tasks = {}

        def on_frame(session: str, done: int, total: int) -> None:
            if session not in tasks:
                tasks[session] = progress.add_task(session, total=total)
            progress.update(tasks[session], completed=done)

        result = run_detection(source, target, config, sinks, frame_step=frame_step, on_frame=on_frame)

    table = Table(title="changes")
    for column in ("kind", "session", "object", "frame", "position (source world)", "masks"):
        table.add_column(column)
    for c in result.changes:
        position = c.center_source if c.center_source is not None else c.center_world
        table.add_row(c.kind, c.session, str(c.object_id), str(c.frame_index),
                      " ".join(f"{v:+.2f}" for v in position), ",".join(map(str, c.instance_ids)))
    console.print(table)
    summary = result.summary()
    line = f"objects: source {summary['objects_source']}, target {summary['objects_target']}; " \
           f"target pass {summary['fps']:.1f} frames/s (" + ", ".join(f"{k} {v:.1f} ms" for k, v in summary["stage_ms"].items()) + ")"
    console.print(line)
    if result.score is not None:
        s = result.score
        console.print(f"ground truth: TP {s.tp}  FP {s.fp}  FN {s.fn}  precision {s.precision:.2f}  recall {s.recall:.2f}")
    for note in result.notes:
        console.print(f"note: {note}")
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        temporary = json_out.with_name(f".{json_out.name}.tmp")
        temporary.write_text(json.dumps(summary, indent=2))
        temporary.replace(json_out)
    for path in (log, tables, json_out):
        if path is not None:
            console.print(f"wrote {path}")


@app.command("segment")
def segment_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The copy to write (.mcap)."),
    keep_truth: bool = typer.Option(False, "--keep-truth", help="Evaluation only: relabel each segment with the "
                                    "ground-truth instance it overlaps with IoU >= 0.5 (else 60000 + label)."),
    stride: Optional[int] = typer.Option(None, help="Sample every N-th pixel along each axis (default: width // 320)."),
) -> None:
    """Copy a recording with its instance masks replaced by the geometric segmentation (planes + DBSCAN)."""
    from ndfa.perception.segmentation import SegmentationConfig
    from ndfa.segment import segment_recording

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=err_console, transient=True) as progress:
        task = progress.add_task("segmenting", total=None)
        count = segment_recording(recording, out, SegmentationConfig(stride=stride), keep_truth=keep_truth,
                                  on_frame=lambda done, total: progress.update(task, completed=done, total=total))
    console.print(f"wrote {out}: {count} frames segmented")


@app.command("eval")
def eval_command(
    source: Optional[Path] = typer.Argument(None, help="Source session recording (.mcap), with instance masks."),
    target: Optional[Path] = typer.Argument(None, help="Target session recording (.mcap), with masks and ground truth."),
    out: Path = typer.Option(..., "--out", "-o", help="Directory for table.parquet and table.md (sweep: sweep.parquet, sweep_AXIS.png)."),
    nn_distance: float = typer.Option(0.002, help="NN: d, metres (the paper's 0.002)."),
    nn_fraction: float = typer.Option(0.3, help="NN: r, share of change points that makes a view changed (paper: 0.3)."),
    tsdf_voxel: float = typer.Option(0.01, help="PMT: submap voxel size, metres (PMT's small-object default: 0.02)."),
    frame_step: int = typer.Option(1, help="Use every N-th frame of both recordings, for all methods."),
    sweep: Optional[str] = typer.Option(None, help="Instead of SOURCE TARGET: sweep an axis of synthetic scenes: "
                                        "drift | noise | objects | overlap."),
    values: Optional[str] = typer.Option(None, help="Sweep: comma-separated values of the axis."),
    seeds: str = typer.Option("0-4", help="Sweep: seeds, N, LO-HI or a comma list."),
    preset: str = typer.Option("sample", help="Sweep: scene preset of every cell (sample | paper | random)."),
    step: Optional[float] = typer.Option(None, help="Sweep: camera travel between frames, metres (preset's default)."),
    workers: Optional[int] = typer.Option(None, help="Sweep: cells in parallel (default: CPU count; 1 = in process)."),
    address: Optional[str] = typer.Option(None, help="Sweep: Ray cluster address (needs the ndfa cluster extra: Ray)."),
    ray: Optional[bool] = typer.Option(None, "--ray/--no-ray", help="Sweep: use Ray (default: when installed)."),
) -> None:
    """The paper's Table I: ndfa (given poses) and the NN and PMT baselines (true poses, ground-truth masks).

    With --sweep: precision/recall/F1 of the three methods over an axis of synthetic scenes and seeds."""
    if sweep is not None:
        if source is not None or target is not None:
            raise typer.BadParameter("--sweep renders its own scenes: give no SOURCE TARGET")
        _eval_sweep(sweep, values, seeds, preset, step, workers, address, ray, out)
        return
    if source is None or target is None:
        raise typer.BadParameter("give SOURCE and TARGET recordings, or --sweep AXIS --values ...")
    from ndfa.baselines.nn import NNConfig
    from ndfa.baselines.table import evaluate_methods, write_table
    from ndfa.baselines.tsdf import TSDFConfig

    if frame_step < 1:
        raise typer.BadParameter(f"--frame-step must be >= 1, got {frame_step}")
    nn, tsdf = NNConfig(distance_m=nn_distance, changed_fraction=nn_fraction), TSDFConfig(voxel_m=tsdf_voxel)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=err_console, transient=True) as progress:
        tasks = {}

        def on_frame(method: str, session: str, done: int, total: int) -> None:
            key = f"{method} {session}"
            if key not in tasks:
                tasks[key] = progress.add_task(key, total=total)
            progress.update(tasks[key], completed=done)

        result = evaluate_methods(source, target, nn, tsdf, frame_step=frame_step, on_frame=on_frame)

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


def _eval_sweep(axis: str, values: Optional[str], seeds: str, preset: str, step: Optional[float],
                workers: Optional[int], address: Optional[str], use_ray: Optional[bool], out: Path) -> None:
    """`ndfa eval --sweep`: run (or resume) the sweep, print the aggregated table, write parquet and PNG."""
    from ndfa.sweep import aggregate, plot_sweep, run_sweep, spec_from_text

    if values is None:
        raise typer.BadParameter("--sweep needs --values, e.g. --values 0,0.001,0.002")
    if workers is not None and workers < 1:
        raise typer.BadParameter(f"--workers must be >= 1, got {workers}")
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
    out: Path = typer.Option(..., "--out", "-o", help="The copy with estimated poses (.mcap)."),
    method: str = typer.Option("kiss-icp", help="Pose estimation method: kiss-icp."),
    tum_out: Optional[Path] = typer.Option(None, help="Also write the estimate as a TUM trajectory file (evo)."),
    voxel_size: Optional[float] = typer.Option(None, help="KISS-ICP map voxel, metres (default 0.03)."),
    max_range: Optional[float] = typer.Option(None, help="Farthest point used, metres (default 4.0)."),
    stride: Optional[int] = typer.Option(None, help="Depth averaged over STRIDE x STRIDE pixel blocks (default 4)."),
    no_refine: bool = typer.Option(False, "--no-refine", help="KISS-ICP alone, without the point-to-plane refinement."),
) -> None:
    """Estimate camera poses from depth, write a copy of the recording with them, and print ATE/RPE."""
    from ndfa.trajectory import OdometryConfig, rewrite_poses, write_tum

    overrides = {"voxel_size_m": voxel_size, "max_range_m": max_range, "pixel_stride": stride}
    config = OdometryConfig(**{k: v for k, v in overrides.items() if v is not None}, refine=not no_refine)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=err_console, transient=True) as progress:
        task = progress.add_task(method, total=None)
        report = rewrite_poses(recording, out, method, config,
                               on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    if tum_out is not None:
        write_tum(tum_out, report.timestamps, report.estimate)
    table = Table(title=f"{method} on {recording}: {report.frames} frames, against the {report.truth}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    if report.ate is not None:
        table.add_row("ATE RMSE (SE(3)-aligned)", f"{100 * report.ate.rmse_m:.2f} cm")
        table.add_row("ATE max", f"{100 * report.ate.max_m:.2f} cm")
    for rpe in report.rpe:
        delta = f"{rpe.delta:g} {'frame' if rpe.unit == 'frames' else 'm'}"
        table.add_row(f"RPE per {delta}: translation RMSE", f"{1000 * rpe.translation_rmse_m:.1f} mm")
        table.add_row(f"RPE per {delta}: rotation RMSE", f"{rpe.rotation_rmse_deg:.3f} deg")
    table.add_row("odometry time", f"{report.ms_per_frame:.0f} ms / frame")
    table.add_row("frames with too little depth", str(report.starved_frames))
    table.add_row("refinements rejected", str(report.refinements_rejected))
    console.print(table)
    for path in (out, tum_out):
        if path is not None:
            console.print(f"wrote {path}")


@app.command("view")
def view_command(rrd: Path = typer.Argument(..., help="A Rerun recording written by `ndfa detect --log`.")) -> None:
    """Open a .rrd in the Rerun viewer."""
    import shutil
    import subprocess

    if not rrd.is_file():
        raise NdfaError(f"{rrd}: no such file")
    viewer = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    raise typer.Exit(subprocess.call([viewer, str(rrd)]))


@app.command("bench")
def bench_command(
    what: str = typer.Argument("sim", help="What to time: sim (render, noise, write, read), ndf (encoding) "
                                            "or detect (the target pass, and the detection step's growth)."),
    frames: int = typer.Option(60, help="sim: frames to time."),
    weights: Optional[Path] = typer.Option(None, help="ndf: checkpoint to time (default: the shipped weights)."),
    source: Path = typer.Option(Path("recordings/sample/source.mcap"), help="detect: source recording."),
    target: Path = typer.Option(Path("recordings/sample/target.mcap"), help="detect: target recording."),
    recording: Path = typer.Option(Path("out/paper/target.mcap"), help="segment: recording with ground-truth masks."),
    step: int = typer.Option(1, help="segment: use every N-th frame."),
) -> None:
    """Time each stage of a pipeline and print milliseconds."""
    from ndfa.bench import bench_detect, bench_detection_scaling, bench_ndf, bench_sim

    if what == "segment":
        from ndfa.perception.segmentation import SegmentationConfig, segmentation_recall
        from ndfa.recording import RecordingReader

        reader = RecordingReader(recording)
        r = segmentation_recall(reader.frames(step=step), SegmentationConfig())
        console.print(f"ndfa bench segment {recording} (every {step}. frame): {r.frames} frames; "
                      f"recovered {r.recovered}/{r.observations} = {r.recall:.1%} of the ground-truth instances with "
                      f">= 200 pixels of depth (IoU >= 0.5); {r.segments} segments, {r.spurious} matching no instance; "
                      f"{r.ms_per_frame:.1f} ms/frame ({r.cpu_ms_per_frame:.1f} ms CPU)")
        return
    if what == "detect":
        result = bench_detect(source, target)
        table = Table(title=f"ndfa bench detect: target pass of {target} (no sinks)",
                      caption=f"{result['frames']} frames, {result['fps']:.1f} frames/s, {result['threads']} threads; "
                              f"{result['machine']}")
        table.add_column("stage")
        table.add_column("ms / frame", justify="right")
        for stage, ms in result["stage_ms"].items():
            table.add_row(stage, f"{ms:.1f}")
        table.add_row("total", f"{result['total_ms']:.1f}")
        console.print(table)
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
        table = Table(title="ndfa bench ndf (encode + center + reconstruction grid)",
                      caption=f"{result['points']} points per observation, grid {result['grid']}^3, "
                              f"{result['threads']} threads; {result['machine']}")
        rows = [("one observation", "one_ms"), ("batch of 8", "batch8_ms"), ("batch of 8, per observation", "batch8_ms_per_observation")]
    else:
        raise typer.BadParameter(f"unknown benchmark {what!r}; expected sim, ndf, detect or segment")
    table.add_column("stage")
    table.add_column("median ms", justify="right")
    for label, key in rows:
        table.add_row(label, f"{result[key]:.1f}")
    console.print(table)


def main() -> None:
    """Entry point: run the app, turning ndfa's own errors into one line on stderr."""
    try:
        app(standalone_mode=False)
    except NdfaError as error:
        err_console.print(f"[red]error:[/red] {error}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except typer.Abort:
        err_console.print("aborted")
        sys.exit(130)
    except Exception as error:  # usage errors arrive here in non-standalone mode
        # typer >= 0.29 vendors its own click (typer.BadParameter is not a click.ClickException):
        # recognise both by what they can do.
        if callable(getattr(error, "show", None)) and isinstance(getattr(error, "exit_code", None), int):
            error.show()
            sys.exit(error.exit_code)
        raise


if __name__ == "__main__":
    main()
