"""`ndfa export bag`: a recording as a ROS1 or ROS2 bag."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.progress import Progress, TextColumn

from ndfa.cli.app import console, err_console
from ndfa.cli.checks import output_path
from ndfa.cli.export import export_app


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
    from ndfa.io.export.bag import export_bag  # lazy: rosbags and PIL

    with Progress(TextColumn("[bold]{task.description}"), console=err_console, transient=True) as progress:
        progress.add_task(f"writing {out.name}", total=None)
        summary = export_bag(recording, out, version=2 if ros2 else 1, storage=storage, compressed=compressed,
                             color_format=color_format)
    console.print(f"wrote {summary.frames} frames to {summary.out} ({summary.size_bytes / 1e6:.1f} MB): "
                  + ", ".join(summary.topics))
