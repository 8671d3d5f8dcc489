"""`ndfa poses`: estimate a recording's camera poses and write a copy with them."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import app, console, progress_bar
from ndfa.cli.checks import at_least_one, output_file, positive
from ndfa.io.tum_format import write_tum
from ndfa.trajectory import OdometryConfig, rewrite_poses

# The help quotes the odometry's defaults (OdometryConfig imports without open3d).
_ODOMETRY = OdometryConfig()


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
