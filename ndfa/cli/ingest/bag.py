"""`ndfa ingest bag`: a ROS1 or ROS2 bag into one recording."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import console, progress_bar
from ndfa.cli.checks import output_file, positive
from ndfa.cli.ingest import ingest_app
from ndfa.cli.ingest.estimated_poses import estimate_session_poses, input_warnings, pose_estimator
from ndfa.io.ingest import MAX_DT_S


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
    from ndfa.io.ingest.bag import ingest_bag, list_topics  # lazy: rosbags and PIL (a quarter of a second)

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
    estimator, monitor = pose_estimator(poses)
    out.parent.mkdir(parents=True, exist_ok=True)  # as `detect --log`; removed again if the import fails

    with progress_bar() as progress:
        task = progress.add_task(f"writing {out.name}", total=None)
        summary = ingest_bag(bag, out, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic,
                             mask_topic=mask_topic, pose_source=pose_topic, world_frame=world_frame,
                             camera_frame=camera_frame, max_dt=max_dt, estimate_poses=estimator, imu_topic=imu_topic,
                             on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    warnings_of_input = input_warnings(monitor, poses, bag, out)

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
    for message in warnings_of_input:
        console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)
    estimate_session_poses(out, poses)
