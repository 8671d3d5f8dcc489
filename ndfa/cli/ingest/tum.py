"""`ndfa ingest tum`: a TUM RGB-D folder into one recording."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.table import Table

from ndfa.cli.app import console, progress_bar
from ndfa.cli.checks import input_dir, non_empty, output_file, positive
from ndfa.cli.ingest import ingest_app
from ndfa.cli.ingest.estimated_poses import estimate_session_poses, input_warnings, pose_estimator
from ndfa.core.color_camera import ColorCamera
from ndfa.core.errors import NdfaError, OptionError
from ndfa.io.ingest import MAX_DT_S
from ndfa.io.ingest.tum_layout import DEFAULT_INTRINSICS, DEPTH_SCALE, INTRINSICS_PRESETS

_PRESETS = " | ".join(INTRINSICS_PRESETS)
MAX_PIXELS = 1e5  # no camera's focal length or principal point, in pixels, comes near


def _parse_frames(text: Optional[str]) -> tuple[int, int | None] | None:
    """'START:STOP', 'START:' or ':STOP' (paired frames, from 0; stop excluded) -> (start, stop)."""
    if text is None:
        return None
    start, colon, stop = text.partition(":")
    try:
        if not colon:
            raise ValueError
        return int(start or 0), int(stop) if stop else None
    except ValueError:
        raise OptionError(f"--frames must be START:STOP (e.g. 0:250, 250: or :250), got {text!r}") from None


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
    if not (np.all(np.isfinite(values)) and 0 < values[0] <= MAX_PIXELS and 0 < values[1] <= MAX_PIXELS
            and max(abs(values[2]), abs(values[3])) <= MAX_PIXELS):
        raise NdfaError(f"--intrinsics: fx and fy must be > 0, and all four at most {MAX_PIXELS:g} pixels "
                        f"(a focal length or centre beyond any camera's image), got {text!r}")
    return values


def _parse_color_camera(text: Optional[str]) -> ColorCamera | None:
    if text is None:
        return None
    try:
        return ColorCamera.parse(text)
    except ValueError as error:
        raise OptionError(f"--color-intrinsics {error}") from None


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
    session: Optional[str] = typer.Option(None, help="Session name (default: the folder's name).", callback=non_empty),
    frames: Optional[str] = typer.Option(None, help="START:STOP: import only these paired frames (from 0, STOP "
                                                    "excluded; e.g. 0:250 and 250: make two sessions of one walk)."),
    color_intrinsics: Optional[str] = typer.Option(
        None, help="fx,fy,cx,cy[,dx] of the colour camera when the colour images are not registered to the depth "
        "(7-Scenes: 525,525,321,240,-0.025; dx its offset along the depth camera's x axis, metres): kept in the "
        "recording, the RGB-D odometry registers the colour to the depth."),
) -> None:
    """Import a TUM RGB-D folder into one recording, and say what was dropped and why."""
    from ndfa.io.ingest.tum import TumWarning, ingest_tum  # lazy: PIL (a twentieth of a second)

    estimator, monitor = pose_estimator(poses)
    camera = _parse_intrinsics(intrinsics)
    frame_range = _parse_frames(frames)
    color_camera = _parse_color_camera(color_intrinsics)
    out.parent.mkdir(parents=True, exist_ok=True)  # as `detect --log`; removed again if the import fails

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TumWarning)  # listed under the table instead
        with progress_bar() as progress:
            task = progress.add_task(f"writing {out.name}", total=None)
            summary = ingest_tum(folder, out, intrinsics=camera, depth_scale=depth_scale,
                                 masks=masks, max_dt=max_dt, session=session, estimate_poses=estimator,
                                 frames=frame_range, color_camera=color_camera,
                                 on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    warnings_of_input = input_warnings(monitor, poses, folder, out)

    table = Table(title=f"{folder} -> {out}", show_header=False)
    table.add_column("what")
    table.add_column("value", justify="right")
    table.add_row("session", summary.session)
    table.add_row("depth frames in depth.txt", str(summary.indexed))
    if summary.selected:
        table.add_row("frames selected (--frames)", summary.selected)
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
    for message in summary.warnings + warnings_of_input:
        console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)
    for message in summary.notes:
        console.print(f"note: {message}", highlight=False, soft_wrap=True)
    estimate_session_poses(out, poses)
