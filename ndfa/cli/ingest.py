"""`ndfa ingest ...`, `ndfa export ...` and `ndfa info`: recordings in and out."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.progress import Progress, TextColumn
from rich.table import Table

from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import (
    at_least,
    at_least_one,
    in_range,
    input_dir,
    non_negative,
    output_dir,
    output_file,
    output_path,
    positive,
)
from ndfa.core.errors import NdfaError
from ndfa.io.ingest import MAX_DT_S
from ndfa.io.ingest.tum_layout import DEFAULT_INTRINSICS, DEPTH_SCALE, INTRINSICS_PRESETS
from ndfa.sim.trajectory import RAW_MAX_TURN_DEG

_PRESETS = " | ".join(INTRINSICS_PRESETS)

ingest_app = typer.Typer(no_args_is_help=True, help="Turn a data source into ndfa recordings (MCAP).")
app.add_typer(ingest_app, name="ingest")

def _parse_range(text: str, what: str) -> tuple[int, int]:
    try:
        lo, _, hi = text.partition("-")
        low, high = int(lo), int(hi or lo)
    except ValueError:
        raise typer.BadParameter(f"{what} must be N or LO-HI, got {text!r}") from None
    if not 0 <= low <= high:
        raise typer.BadParameter(f"{what} must be N or LO-HI with 0 <= LO <= HI, got {text!r}")
    return low, high


def _pose_estimator(poses: str):
    """The importers' `--poses`: (None, None) for "given" (the input's own), else a per-frame
    placeholder pose (the frame's own, the identity when it has none) that checks each frame's
    input, and the monitor of those checks. The placeholders are replaced afterwards by the
    whole-session estimate (`_estimate_session_poses`): running the odometry while writing as well
    would only do it twice."""
    if poses == "given":
        return None, None
    if poses not in ("estimate", "rgbd", "kiss-icp"):
        raise NdfaError(f"--poses must be given, estimate, rgbd or kiss-icp, got {poses!r}")
    from ndfa.trajectory.checks import InputMonitor

    monitor = InputMonitor()

    def placeholder(frame):
        monitor.observe(frame)
        return np.asarray(frame.pose_world_camera, dtype=np.float64)

    return placeholder, monitor


def _input_warnings(monitor, poses: str, source: Path, out: Path) -> list[str]:
    """The input checks' warnings after an import with estimated poses; when no frame could be
    tracked, the recording is removed and the import fails in one line naming the input."""
    if monitor is None:
        return []
    uses_colour = poses != "kiss-icp" and any(check.textured is not None for check in monitor.checks)
    report = monitor.report(uses_colour)
    if report.untrackable is not None:
        out.unlink(missing_ok=True)
        raise NdfaError(f"{source}: {report.untrackable}; nothing written")
    from ndfa.trajectory.session import UNTRACKED_POSES

    return report.warnings(untracked_poses=UNTRACKED_POSES)


def _estimate_session_poses(out: Path, poses: str) -> None:
    """After an import with `--poses estimate|rgbd|kiss-icp`: the whole-session estimate (loop
    closure needs every frame) replaces the poses written frame by frame; its errors are printed
    when the input had true poses."""
    if poses == "given":
        return
    from ndfa.trajectory.rewrite import estimate_poses_in_place

    with progress_bar() as progress:
        task = progress.add_task(f"poses of {out.name}", total=None)
        report = estimate_poses_in_place(out, poses, on_progress=lambda done, total: progress.update(
            task, completed=done, total=total), check_input=False)  # the import has checked and warned
    table = Table(title=f"{report.method} poses of {out}: {report.frames} frames, against the {report.truth}",
                  show_header=False)
    table.add_column("figure")
    table.add_column("value", justify="right")
    for figure, value in report.rows():
        table.add_row(figure, value)
    console.print(table)


@ingest_app.command("sim")
def ingest_sim_command(
    out: Path = typer.Option(..., "--out", "-o", help="Output directory for source.mcap and target.mcap "
                             "(with --sessions N > 2: session_0.mcap ... session_{N-1}.mcap).", callback=output_dir),
    preset: str = typer.Option("paper", help="paper | sample | random."),
    sessions: int = typer.Option(2, help="Sessions to render, with the change counts applied between each "
                                         "consecutive pair (docs/sessions.md).", callback=in_range(ge=2, le=100)),
    seed: int = typer.Option(0, help="Seed of everything random in the scene.", callback=at_least(0)),
    mesh_dir: Optional[Path] = typer.Option(None, help="Place these OBJ/PLY/STL/GLB mug meshes instead of procedural "
                                             "ones (units and up axis guessed unless --mesh-up is given).",
                                             callback=input_dir),
    mesh_up: str = typer.Option("auto", help="Up axis of the --mesh-dir meshes: auto (guessed per mesh, with a note) | z | y."),
    tables: Optional[str] = typer.Option(None, help="Table grid as ROWSxCOLS, e.g. 2x4."),
    mugs_per_table: Optional[str] = typer.Option(None, help="Mugs per table in the source, N or LO-HI."),
    models: Optional[int] = typer.Option(None, help="Number of distinct procedural mug models.", callback=at_least_one),
    added: Optional[int] = typer.Option(None, help="Mugs added in the target.", callback=non_negative),
    removed: Optional[int] = typer.Option(None, help="Mugs removed in the target.", callback=non_negative),
    moved: Optional[int] = typer.Option(None, help="Mugs moved in the target.", callback=non_negative),
    switched: Optional[int] = typer.Option(None, help="Mugs that switch places (an even number).",
                                           callback=non_negative),
    source_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    target_route: Optional[str] = typer.Option(None, help="perimeter | corridor | weave | circles."),
    step: Optional[float] = typer.Option(None, help="Camera travel between frames, metres.", callback=positive),
    noise: Optional[bool] = typer.Option(None, "--noise/--no-noise", help="Depth sensor noise on or off."),
    noise_scale: Optional[float] = typer.Option(None, help="Depth noise std as a multiple of the default sensor's.",
                                                callback=non_negative),
    offset: Optional[float] = typer.Option(None, help="Target pose offset: max translation per axis, metres.",
                                           callback=non_negative),
    offset_yaw: Optional[float] = typer.Option(None, help="Target pose offset: max yaw, degrees.",
                                               callback=non_negative),
    drift: Optional[float] = typer.Option(None, help="Target drift: random-walk translation step std, metres/frame.",
                                          callback=non_negative),
    drift_yaw: Optional[float] = typer.Option(None, help="Target drift: random-walk yaw step std, degrees/frame.",
                                              callback=non_negative),
    textures: bool = typer.Option(False, "--textures", help="Procedural colour texture on walls, floor and table tops."),
    clutter: int = typer.Option(0, help="Non-mug objects per table (boxes, books, bowls, bottles); static, listed "
                                        "as clutter in the ground truth.", callback=non_negative),
    raw: bool = typer.Option(False, "--raw", help="Record as a sensor does: no instance masks, no camera poses "
                                                  "(/tf); the true poses stay in the ground truth."),
    world_tilt: float = typer.Option(0.0, help="Tilt the recorded world frame this many degrees away from z-up "
                                               "(random roll/pitch axis from the seed).",
                                   callback=in_range(gt=-90, lt=90)),
    max_turn: Optional[float] = typer.Option(None, help="Most the camera turns between frames, degrees; 0: unlimited "
                                                        f"(default: {RAW_MAX_TURN_DEG:g} with --raw, else unlimited).",
                                            callback=in_range(ge=0, le=180)),
    rotated: int = typer.Option(0, help="Mugs turned in place about up in the target (unchanged mugs with a handle).",
                                callback=non_negative),
    rotated_deg: tuple[float, float] = typer.Option((45.0, 180.0), help="MIN MAX: the range (degrees) each "
                                                    "--rotated mug turns by, in either sense."),
) -> None:
    """Render a synthetic source/target pair of recordings (or N sessions) with ground truth."""
    from ndfa.io.ingest.synthetic import check_output_dir, ingest_sim
    from ndfa.sim.noise import DepthNoise
    from ndfa.sim.presets import make_config

    config = make_config(preset, seed)
    overrides: dict = {}
    if tables is not None:
        rows, _, cols = tables.lower().partition("x")
        if not (rows.isdigit() and cols.isdigit() and int(rows) >= 1 and int(cols) >= 1):
            raise typer.BadParameter(f"--tables must be ROWSxCOLS (each at least 1), got {tables!r}")
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
    if max_turn is None:
        max_turn = RAW_MAX_TURN_DEG if raw else 0.0
    if max_turn:
        trajectory = overrides.get("trajectory", config.trajectory)
        overrides["trajectory"] = dataclasses.replace(trajectory, max_turn_deg=max_turn)
    if noise is not None or noise_scale is not None:
        overrides["depth_noise"] = DepthNoise().scaled(1.0 if noise_scale is None else noise_scale)
        if noise is False:
            overrides["depth_noise"] = DepthNoise.off()
    error = {k: v for k, v in dict(offset_translation_m=offset, offset_yaw_deg=offset_yaw,
                                   drift_translation_m=drift, drift_yaw_deg=drift_yaw).items() if v is not None}
    if error:
        overrides["target_pose_error"] = dataclasses.replace(config.target_pose_error, **error)
    overrides.update(textures=textures, clutter_per_table=clutter, raw=raw, world_tilt_deg=world_tilt,
                     rotated=rotated, rotated_deg=tuple(rotated_deg))
    config = make_config(preset, seed, **overrides)

    check_output_dir(out)
    user_models = None
    if mesh_dir is not None:
        from ndfa.sim.mesh_io import load_mug_dir

        user_models = load_mug_dir(mesh_dir, up=mesh_up, on_note=lambda note: err_console.print(
            f"note: {note}", highlight=False, soft_wrap=True))

    with progress_bar(transient=False) as progress:
        summaries = ingest_sim(config, out, models=user_models, on_progress=bar_per_label(progress, "rendering "),
                               sessions=sessions)

    table = Table(title=f"{config.preset} scene, seed {config.seed}: {config.table_rows * config.table_cols} tables -> {out}")
    kinds = ("added", "removed", "moved", "switched") + (("rotated",) if rotated else ())
    for column in ("session", "frames", "mugs", *kinds, "size"):
        table.add_column(column, justify="left" if column == "session" else "right")
    for s in summaries:
        table.add_row(s.path.name, str(s.frames), str(s.objects),
                      *(str(s.changes.get(k, "")) for k in kinds),
                      f"{s.size_bytes / 1e6:.1f} MB")
    console.print(table)


def _parse_intrinsics(text: Optional[str]) -> object:
    """None, a TUM preset name (fr1, fr2, fr3) or 'fx,fy,cx,cy' -> what ingest_tum takes."""
    if text is None or text.lower() in INTRINSICS_PRESETS:
        return text.lower() if text else None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise NdfaError(f"--intrinsics must be {', '.join(INTRINSICS_PRESETS)} or fx,fy,cx,cy, got {text!r}")
    if not (np.all(np.isfinite(values)) and values[0] > 0 and values[1] > 0):
        raise NdfaError(f"--intrinsics: fx and fy must be finite and > 0, cx and cy finite, got {text!r}")
    return values


@ingest_app.command("tum")
def ingest_tum_command(
    folder: Path = typer.Argument(..., help="A TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt, rgb/, depth/)."),
    out: Path = typer.Option(..., "--out", "-o", help="The recording to write (.mcap).", callback=output_file),
    intrinsics: Optional[str] = typer.Option(None, help=f"{_PRESETS} | fx,fy,cx,cy (default: the folder's "
                                             "calibration.txt, else TUM's ROS default "
                                             f"{','.join(f'{v:g}' for v in DEFAULT_INTRINSICS)})."),
    depth_scale: float = typer.Option(DEPTH_SCALE, help="Depth PNG units per metre (TUM: 5000).", callback=positive),
    masks: Optional[Path] = typer.Option(None, help="Instance masks: 16-bit PNGs named as the depth PNGs, 0 = none "
                                                    "(default: the folder's masks/ if any).", callback=input_dir),
    max_dt: float = typer.Option(MAX_DT_S, help="Largest rgb-depth timestamp difference to pair them, seconds.",
                                 callback=positive),
    poses: str = typer.Option("given", help="given (groundtruth.txt; without it the recording keeps no poses and "
                                            "`ndfa detect` estimates them) | estimate | rgbd | kiss-icp (estimated "
                                            "now; groundtruth.txt, if any, is kept as the true poses)."),
    session: Optional[str] = typer.Option(None, help="Session name (default: the folder's name)."),
) -> None:
    """Import a TUM RGB-D folder into one recording, and say what was dropped and why."""
    import warnings

    from ndfa.io.ingest.tum import TumWarning, ingest_tum

    estimator, monitor = _pose_estimator(poses)
    camera = _parse_intrinsics(intrinsics)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TumWarning)  # listed under the table instead
        with progress_bar() as progress:
            task = progress.add_task(f"writing {out.name}", total=None)
            summary = ingest_tum(folder, out, intrinsics=camera, depth_scale=depth_scale,
                                 masks=masks, max_dt=max_dt, session=session, estimate_poses=estimator,
                                 on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    input_warnings = _input_warnings(monitor, poses, folder, out)

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
    for message in summary.warnings + input_warnings:
        console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)
    for message in summary.notes:
        console.print(f"note: {message}", highlight=False, soft_wrap=True)
    _estimate_session_poses(out, poses)


@ingest_app.command("bag")
def ingest_bag_command(
    bag: Path = typer.Argument(..., help="A ROS1 .bag file or a ROS2 bag directory (sqlite3 or mcap)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="The recording to write (.mcap).",
                                       callback=output_file),
    list_only: bool = typer.Option(False, "--list", help="List the bag's topics and the role each would get; write nothing."),
    rgb_topic: Optional[str] = typer.Option(None, help="Colour images (Image or CompressedImage)."),
    depth_topic: Optional[str] = typer.Option(None, help="Depth images (16UC1 mm, 32FC1 m, or compressedDepth)."),
    info_topic: Optional[str] = typer.Option(None, help="The depth camera's sensor_msgs/CameraInfo."),
    mask_topic: Optional[str] = typer.Option(None, help="Instance masks (mono16/16UC1, 0 = none)."),
    pose_topic: Optional[str] = typer.Option(None, help="tf, or a nav_msgs/Odometry or geometry_msgs/PoseStamped topic "
                                                        "(default: tf when the bag has it)."),
    world_frame: Optional[str] = typer.Option(None, help="tf frame of the world (default: map, odom or world)."),
    camera_frame: Optional[str] = typer.Option(None, help="tf frame of the camera (default: the depth images' frame_id)."),
    max_dt: float = typer.Option(MAX_DT_S, help="Largest depth-colour (and depth-mask) stamp difference, seconds.",
                                 callback=positive),
    poses: str = typer.Option("given", help="given (from the bag) | estimate | rgbd | kiss-icp (estimated)."),
    imu_topic: Optional[str] = typer.Option(None, help="sensor_msgs/Imu topic whose still readings give world up "
                                                       "(default: the bag's one Imu topic, if any)."),
) -> None:
    """Import a ROS1 or ROS2 bag into one recording, and say what was skipped and why."""
    from ndfa.io.ingest.bag import ingest_bag, list_topics

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
    estimator, monitor = _pose_estimator(poses)

    with progress_bar() as progress:
        task = progress.add_task(f"writing {out.name}", total=None)
        summary = ingest_bag(bag, out, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic,
                             mask_topic=mask_topic, pose_source=pose_topic, world_frame=world_frame,
                             camera_frame=camera_frame, max_dt=max_dt, estimate_poses=estimator, imu_topic=imu_topic,
                             on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    input_warnings = _input_warnings(monitor, poses, bag, out)

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
    table.add_row("IMU (world up)", summary.imu)
    table.add_row("size", f"{summary.size_bytes / 1e6:.1f} MB")
    console.print(table)
    for message in input_warnings:
        console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)
    _estimate_session_poses(out, poses)


export_app = typer.Typer(no_args_is_help=True, help="Write ndfa recordings out in other formats.")
app.add_typer(export_app, name="export")


@export_app.command("tum")
def export_tum_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The TUM folder to create (must not exist, or be empty).",
                             callback=output_dir),
    depth_scale: float = typer.Option(DEPTH_SCALE, help="Depth PNG units per metre (TUM: 5000).", callback=positive),
) -> None:
    """Write a recording as a TUM RGB-D folder (plus calibration.txt, masks/ and ground truth)."""
    from ndfa.io.export.tum import export_tum

    with progress_bar() as progress:
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
    out: Path = typer.Option(..., "--out", "-o", help="The bag to create: a .bag file, or a directory with --ros2.",
                             callback=output_path),
    ros2: bool = typer.Option(False, "--ros2", help="Write a ROS2 bag (directory) instead of a ROS1 .bag."),
    storage: str = typer.Option("sqlite3", help="ROS2 storage: sqlite3 | mcap."),
    compressed: bool = typer.Option(False, "--compressed", help="Colour as CompressedImage, depth as compressedDepth PNG."),
    color_format: str = typer.Option("jpeg", help="With --compressed: jpeg (lossy) | png."),
) -> None:
    """Write a recording as a ROS bag (images, CameraInfo, /tf, /tf_static, ground truth)."""
    from ndfa.io.export.bag import export_bag

    with Progress(TextColumn("[bold]{task.description}"), console=err_console, transient=True) as progress:
        progress.add_task(f"writing {out.name}", total=None)
        summary = export_bag(recording, out, version=2 if ros2 else 1, storage=storage, compressed=compressed,
                             color_format=color_format)
    console.print(f"wrote {summary.frames} frames to {summary.out} ({summary.size_bytes / 1e6:.1f} MB): "
                  + ", ".join(summary.topics))


@app.command("info")
def info_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    up: str = typer.Option("auto", help="World up: auto (a synthetic recording's z, otherwise estimated) | "
                                        "estimate | z (not checked)."),
) -> None:
    """Summarise a recording: source, frames, poses, world up, masks and ground-truth changes."""
    from ndfa.core.errors import RecordingError
    from ndfa.io.recording import RecordingReader
    from ndfa.run.world import UP_MODES, prepare_session

    if up not in UP_MODES:
        raise typer.BadParameter(f"--up must be one of {', '.join(UP_MODES)}, got {up!r}")
    reader = RecordingReader(recording)
    meta = reader.meta
    table = Table(title=str(recording), show_header=False)
    table.add_column("key")
    table.add_column("value")
    for key in ("source", "session", "preset", "seed", "route", "poses"):
        if key in meta:
            table.add_row(key, str(meta[key]))
    table.add_row("frames", str(len(reader)))
    if reader.has_poses:  # without poses, up is found by `ndfa detect` after estimating them
        try:
            world = prepare_session(reader, meta.get("session", ""), up=up, poses="given")
            table.add_row("world up", world.describe_up())
        except RecordingError as error:
            table.add_row("world up", f"not found: {error}")
    else:
        table.add_row("world up", "estimated by `ndfa detect` once it has estimated the poses (the recording has none)")
    imu = meta.get("imu")
    if isinstance(imu, dict):  # a bag's IMU: what it gave for world up (ndfa.io.ingest.bag_imu)
        rotated = f"; into the camera by {imu['camera_from_imu']}" if imu.get("camera_from_imu") else ""
        table.add_row("IMU", f"{imu.get('topic', '?')}: {imu.get('note', '')}{rotated}")
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
