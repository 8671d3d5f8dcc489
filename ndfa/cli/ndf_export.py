"""`ndfa ndf-export`: a training checkpoint stripped to the weights the package ships."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ndfa.cli.app import app, console
from ndfa.cli.checks import checkpoint, output_file


@app.command("ndf-export")
def ndf_export_command(
    checkpoint: Path = typer.Argument(..., help="A training checkpoint (RUN/checkpoint.pt).", callback=checkpoint),
    to: Optional[Path] = typer.Option(None, help="Destination (default: the package's shipped weights).",
                                      callback=output_file),
) -> None:
    """Strip a training checkpoint to the weights the package ships and loads by default."""
    # lazy: both import torch (seconds)
    from ndfa.ndf.encoder import DEFAULT_WEIGHTS
    from ndfa.training.checkpoint import export_weights

    destination = to or DEFAULT_WEIGHTS
    export_weights(checkpoint, destination)
    console.print(f"wrote {destination} ({destination.stat().st_size / 1e6:.2f} MB)")
