"""`ndfa plant`: plant changes into a pair of real recordings, to measure ndfa on one's own data."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import at_least_one, input_file, non_negative, output_dir, output_file


@app.command("plant")
def plant_command(
    source: Path = typer.Argument(..., help="The source session's recording (.mcap), with camera poses.",
                                  callback=input_file),
    target: Path = typer.Argument(..., help="The target session's recording (.mcap), its poses in the same world.",
                                  callback=input_file),
    out: Path = typer.Option(..., "--out", "-o", help="Folder to write source.mcap and target.mcap into.",
                             callback=output_dir),
    plan: Optional[Path] = typer.Option(None, help="The objects to plant (TOML; docs/plant.md): real objects kept "
                                        "or removed, meshes added, moved or removed, by position.",
                                        callback=input_file),
    auto: bool = typer.Option(False, "--auto", help="Place the meshes by --seed on the largest support surface both "
                              "recordings saw: one mug moved (>= 0.5 m where the surface allows), one added, "
                              "and one of the plan's real objects removed."),
    seed: int = typer.Option(0, help="The placements of --auto.", callback=non_negative),
    log: Optional[Path] = typer.Option(None, help="Write frames before and after planting to this Rerun file (.rrd).",
                                       callback=output_file),
    preview_every: int = typer.Option(25, help="Every N-th frame in the --log preview.", callback=at_least_one),
) -> None:
    """Plant changes into a pair of recordings: a real object removed (the support behind it, depth and
    colour), meshes added or moved (ray cast with the recording's intrinsics and a sensor noise model,
    hidden by nearer real surfaces), and their ground truth written, so that `ndfa detect` scores by it."""
    from ndfa.run.plant import run_plant
    from ndfa.run.plant_plan import read_plan

    objects = [] if plan is None else read_plan(plan)
    if not objects and not auto:
        err_console.print("warning: nothing to plant (no --plan, no --auto): the copies equal the recordings")
    with progress_bar() as progress:
        result = run_plant(source, target, out, objects, auto_seed=seed if auto else None, log=log,
                           preview_every=preview_every, on_frame=bar_per_label(progress, "planting "))
    table = Table(title=f"planted -> {out}")
    for column in ("object", "change", "source (x, y)", "target (x, y)"):
        table.add_column(column)
    for obj in result.objects:
        def at(xy):
            return "-" if xy is None else f"{xy[0]:.2f}, {xy[1]:.2f}"
        table.add_row(obj.name, obj.change, at(obj.source_xy), at(obj.target_xy))
    console.print(table)
    for session, path in result.paths.items():
        err_console.print(f"{session}: {path} ({result.frames[session]} frames, {result.edited[session]} edited)")
    for note in result.notes:
        err_console.print(f"note: {note}", highlight=False)
