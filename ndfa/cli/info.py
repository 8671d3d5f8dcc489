"""`ndfa info`: what a recording holds."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from ndfa.cli.app import app, console
from ndfa.core.errors import RecordingError
from ndfa.io.recording import RecordingReader
from ndfa.run.world import UP_MODES, prepare_session


@app.command("info")
def info_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    up: str = typer.Option("auto", help="World up: auto (a synthetic recording's z, otherwise estimated) | "
                                        "estimate | z (not checked)."),
) -> None:
    """Summarise a recording: source, frames, poses, world up, masks and ground-truth changes."""
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
