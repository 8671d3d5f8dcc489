"""`ndfa export tum`: a recording as a TUM RGB-D folder."""

from __future__ import annotations

from pathlib import Path

import typer

from ndfa.cli.app import console, progress_bar
from ndfa.cli.checks import output_dir, positive
from ndfa.cli.export import export_app
from ndfa.io.ingest.tum_layout import DEPTH_SCALE


@export_app.command("tum")
def export_tum_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The TUM folder to create (must not exist, or be empty).",
                             callback=output_dir),
    depth_scale: float = typer.Option(DEPTH_SCALE, help="Depth PNG units per metre (TUM: 5000).", callback=positive),
) -> None:
    """Write a recording as a TUM RGB-D folder (plus calibration.txt, masks/ and ground truth)."""
    from ndfa.io.export.tum import export_tum  # lazy: PIL

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
