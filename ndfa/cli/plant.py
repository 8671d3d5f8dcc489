"""`ndfa plant`: plant changes into a pair of real recordings, to measure ndfa on one's own data."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table

from ndfa.cli.app import app, bar_per_label, console, err_console, progress_bar
from ndfa.cli.checks import at_least_one, input_file, output_dir, output_file, seed_range


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
                              "and one of the real objects removed: the plan's, or without a plan those found "
                              "(segments in most frames that see their place, in both sessions)."),
    seed: int = typer.Option(0, help="The placements of --auto.", callback=seed_range),
    log: Optional[Path] = typer.Option(None, help="Write frames before and after planting to this Rerun file (.rrd).",
                                       callback=output_file),
    preview_every: int = typer.Option(25, help="Every N-th frame in the --log preview.", callback=at_least_one),
    frame_step: int = typer.Option(1, help="Write only every N-th frame (then `ndfa detect` each frame of the "
                                   "copies, as --frame-step N would on the whole).", callback=at_least_one),
    color_intrinsics: Optional[str] = typer.Option(
        None, help="fx,fy,cx,cy[,dx] of the colour camera when the colour images are not registered to the "
        "depth: its intrinsics and its offset dx (metres) along the depth camera's x axis (7-Scenes: "
        "525,525,321,240,-0.025 beside its depth's 585,585,320,240; docs/plant.md)."),
) -> None:
    """Plant changes into a pair of recordings: a real object removed (the support behind it, depth and
    colour), meshes added or moved (ray cast with the recording's intrinsics and a sensor noise model,
    hidden by nearer real surfaces), and their ground truth written, so that `ndfa detect` scores by it."""
    from ndfa.run.plant import run_plant
    from ndfa.run.plant_plan import read_plan

    color_K, color_offset = (None, 0.0) if color_intrinsics is None else _color_camera(color_intrinsics)
    objects = [] if plan is None else read_plan(plan)
    if not objects and not auto:
        err_console.print("warning: nothing to plant (no --plan, no --auto): the copies equal the recordings")
    with progress_bar() as progress:
        result = run_plant(source, target, out, objects, auto_seed=seed if auto else None, log=log,
                           preview_every=preview_every, color_K=color_K, color_offset_m=color_offset,
                           frame_step=frame_step,
                           on_frame=bar_per_label(progress, "planting "))
    table = Table(title=f"planted -> {out}")
    for column in ("object", "change", "source (x, y)", "target (x, y)"):
        table.add_column(column)
    for obj in result.objects:
        def at(xy):
            return "-" if xy is None else f"{xy[0]:.2f}, {xy[1]:.2f}"
        table.add_row(escape(obj.name), obj.change, at(obj.source_xy), at(obj.target_xy))
    console.print(table)
    for session, path in result.paths.items():
        err_console.print(f"{session}: {path} ({result.frames[session]} frames, {result.edited[session]} edited)")
    for note in result.notes:
        err_console.print(f"note: {note}", highlight=False, markup=False)


def _color_camera(text: str):
    import math

    import numpy as np

    from ndfa.core.errors import OptionError

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (4, 5) or not all(math.isfinite(v) for v in values) or min(values[:2]) <= 0:
        raise OptionError(f"--color-intrinsics must be fx,fy,cx,cy or fx,fy,cx,cy,dx (finite numbers, positive "
                          f"focal lengths), got {text!r}")
    fx, fy, cx, cy = values[:4]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), (values[4] if len(values) == 5 else 0.0)
