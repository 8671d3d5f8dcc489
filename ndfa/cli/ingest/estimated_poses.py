"""The importers' `--poses estimate | rgbd | kiss-icp` (`ndfa ingest tum`, `ndfa ingest bag`): each frame
checked as it is written, then the whole session's poses estimated in place."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.table import Table

from ndfa.cli.app import console, progress_bar
from ndfa.core.errors import NdfaError
from ndfa.trajectory.checks import InputMonitor
from ndfa.trajectory.rewrite import estimate_poses_in_place
from ndfa.trajectory.session import UNTRACKED_POSES


def pose_estimator(poses: str):
    """The importers' `--poses`: (None, None) for "given" (the input's own), else a per-frame
    placeholder pose (the frame's own, the identity when it has none) that checks each frame's
    input, and the monitor of those checks. The placeholders are replaced afterwards by the
    whole-session estimate (`estimate_session_poses`): running the odometry while writing as well
    would only do it twice."""
    if poses == "given":
        return None, None
    if poses not in ("estimate", "rgbd", "kiss-icp"):
        raise NdfaError(f"--poses must be given, estimate, rgbd or kiss-icp, got {poses!r}")
    monitor = InputMonitor()

    def placeholder(frame):
        monitor.observe(frame)
        return np.asarray(frame.pose_world_camera, dtype=np.float64)

    return placeholder, monitor


def input_warnings(monitor, poses: str, source: Path, out: Path) -> list[str]:
    """The input checks' warnings after an import with estimated poses; when no frame could be
    tracked, the recording is removed and the import fails in one line naming the input."""
    if monitor is None:
        return []
    uses_colour = poses != "kiss-icp" and any(check.textured is not None for check in monitor.checks)
    report = monitor.report(uses_colour)
    if report.untrackable is not None:
        out.unlink(missing_ok=True)
        raise NdfaError(f"{source}: {report.untrackable}; nothing written")
    return report.warnings(untracked_poses=UNTRACKED_POSES)


def estimate_session_poses(out: Path, poses: str) -> None:
    """After an import with `--poses estimate|rgbd|kiss-icp`: the whole-session estimate (loop
    closure needs every frame) replaces the poses written frame by frame; its errors are printed
    when the input had true poses."""
    if poses == "given":
        return
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
