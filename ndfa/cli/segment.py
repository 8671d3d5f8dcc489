"""`ndfa segment`: a copy of a recording with the geometric segmentation as its instance masks."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ndfa.cli.app import app, console, progress_bar
from ndfa.cli.checks import at_least_one, output_file
from ndfa.perception.segmentation_config import SegmentationConfig


@app.command("segment")
def segment_command(
    recording: Path = typer.Argument(..., help="An ndfa recording (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="The copy to write (.mcap).", callback=output_file),
    keep_truth: bool = typer.Option(False, "--keep-truth", help="Evaluation only: relabel each segment with the "
                                    "ground-truth instance it overlaps with IoU >= 0.5 (else 60000 + label)."),
    stride: Optional[int] = typer.Option(None, help="Sample every N-th pixel along each axis (default: width // 320).",
                                         callback=at_least_one),
) -> None:
    """Copy a recording with its instance masks replaced by the geometric segmentation (planes + DBSCAN)."""
    from ndfa.eval.segmentation import relabel_to_truth  # lazy, as the segmentation: scipy.ndimage
    from ndfa.run.segment import segment_recording  # lazy: scipy.ndimage and PIL, a tenth of a second

    with progress_bar() as progress:
        task = progress.add_task("segmenting", total=None)
        count = segment_recording(recording, out, SegmentationConfig(stride=stride),
                                  relabel=relabel_to_truth if keep_truth else None,
                                  on_frame=lambda done, total: progress.update(task, completed=done, total=total))
    console.print(f"wrote {out}: {count} frames segmented")
