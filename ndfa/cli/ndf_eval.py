"""`ndfa ndf-eval`: the model's quality on unseen mugs, or on real ones (`--real`: `ndfa.cli.real_mugs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ndfa.cli.app import app, console
from ndfa.cli.checks import at_least, at_least_one, category_list, checkpoint, in_range, output_dir, seed_range
from ndfa.cli.real_mugs import real_mugs_command
from ndfa.io.atomic import write_parquet


@app.command("ndf-eval")
def ndf_eval_command(
    weights: list[Path] = typer.Option(None, "--weights", "-w", help="Checkpoint(s) to evaluate, or shipped weights by name: mugs | objects (default: mugs).",
                                       callback=checkpoint),
    out: Path = typer.Option(Path("out/ndf-eval"), "--out", "-o", help="Directory for summary.parquet and views.parquet.",
                             callback=output_dir),
    mugs: int = typer.Option(20, help="Held-out test-split objects of each category.", callback=at_least_one),
    views_per_mug: int = typer.Option(50, help="Partial views per object.", callback=at_least_one),
    categories: str = typer.Option("mug", help="Object categories, comma-separated (mug,bowl,cup,bottle,can,box or all): "
                                   "with several, each is reported on its own.", callback=category_list),
    seed: int = typer.Option(0, help="Seed of the test views.", callback=seed_range),
    v0: float = typer.Option(0.5, help="Occupancy threshold of the reconstruction (the IoU is also swept over a few).",
                             callback=in_range(gt=0, lt=1)),
    split: str = typer.Option("test", help="Mug split: test (held out), or train to tune on validation mugs the run did not fit."),
    first_mug: int = typer.Option(0, help="Index of the first mug in the split (e.g. 1000: the validation mugs after 1,000 training ones).",
                                  callback=at_least(0)),
    iou: bool = typer.Option(True, help="Also the reconstruction IoU on a 32^3 grid (most of the time)."),
    real: Optional[Path] = typer.Option(None, "--real", help="Instead: the real-mug protocol on this TUM folder or .mcap "
                                        "with given poses (docs/real_mugs.md)."),
    frame_step: int = typer.Option(2, help="With --real: segment every n-th frame.", callback=at_least_one),
) -> None:
    """Model quality on unseen test-split mugs (or objects: --categories): center error, shape-code retrieval, IoU,
    category accuracy (--real: on real mugs)."""
    if real is not None:
        return real_mugs_command(real, weights, out, frame_step)
    # lazy: polars, and the views' renderer and the model's torch and open3d (seconds)
    import polars as pl

    from ndfa.training.dataset import generate_views
    from ndfa.training.ndf_eval import TRACK_VIEWS, evaluate_ndf
    from ndfa.training.views import ViewConfig

    if split not in ("test", "train"):
        raise typer.BadParameter(f"--split must be test or train, got {split!r}")
    names = tuple(categories.split(","))
    views = generate_views(split, list(range(first_mug, first_mug + mugs)), views_per_mug, seed, ViewConfig(), categories=names)
    rows = []
    out.mkdir(parents=True, exist_ok=True)
    for path in weights or [None]:
        summary, per_view = evaluate_ndf(path, views=views, v0=v0, iou_grid=32 if iou else 0)
        name = str(path) if path is not None else "shipped"
        rows.append({"weights": name, **summary})
        write_parquet(per_view.with_columns(pl.lit(name).alias("weights")), out / f"views-{len(rows)}.parquet")
    table = Table(title=f"ndfa ndf-eval: {split}-split {categories} {first_mug}-{first_mug + mugs - 1} x {views_per_mug} views")
    table.add_column("figure")
    for row in rows:
        table.add_column(Path(row["weights"]).parent.name or row["weights"], justify="right")
    for key in dict.fromkeys(key for row in rows for key in row):  # a v2 model has no category figures
        if key != "weights":
            table.add_row(key, *(f"{row.get(key, float('nan')):.3f}" for row in rows))
    console.print(table)
    for row in rows:  # the headline: the detector's regime
        console.print(
            f"[bold]{row['weights']}[/bold], {row['views_within_2m']:.0f} views with the object within 2 m and >= 300 points: "
            f"center {row['center_median_mm_head_within_2m']:.1f} / {row['center_p90_mm_head_within_2m']:.1f} mm (median / p90), "
            f"retrieval top-1 {row.get('retrieval_top1_within_2m', float('nan')):.3f}, "
            f"box twins merged {row.get('retrieval_top1_within_2m_twins_merged', float('nan')):.3f}"
            + (f", category accuracy {row['category_accuracy_within_2m']:.3f}" if "category_accuracy_within_2m" in row else ""))
        for name in names:
            if f"{name}_center_median_mm_within_2m" in row:
                console.print(
                    f"  {name}: {row[f'{name}_views_within_2m']:.0f} views, center {row[f'{name}_center_median_mm_within_2m']:.1f}"
                    f" / {row[f'{name}_center_p90_mm_within_2m']:.1f} mm, retrieval top-1 "
                    f"{row.get(f'{name}_retrieval_top1_within_2m', float('nan')):.3f}"
                    + (f", category accuracy {row[f'{name}_category_accuracy_within_2m']:.3f}"
                       if f"{name}_category_accuracy_within_2m" in row else "")
                    + (f"; tracks of {TRACK_VIEWS} views: retrieval top-1 {row[f'{name}_track_retrieval_top1']:.3f}"
                       if f"{name}_track_retrieval_top1" in row else "")
                    + (f", category accuracy {row[f'{name}_track_category_accuracy']:.3f}"
                       if f"{name}_track_category_accuracy" in row else ""))
    write_parquet(pl.DataFrame(rows), out / "summary.parquet")
    console.print(f"tables in {out}")
