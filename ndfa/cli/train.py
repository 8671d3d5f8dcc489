"""`ndfa train`: train the NDF on rendered partial views of procedural mugs (or of several object
categories: --categories, NDF v3)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from ndfa.cli.app import app, console, err_console
from ndfa.cli.checks import (
    at_least,
    at_least_one,
    category_list,
    checkpoint,
    fraction,
    in_range,
    non_negative,
    output_dir,
    output_file,
    positive,
    seed_range,
    thread_count,
)
from ndfa.io.atomic import outside_all_or_nothing
from ndfa.ndf.config import NDFConfig
from ndfa.sim.sensor_artifacts import SensorArtifacts


@app.command("train")
def train_command(
    out: Path = typer.Option(Path("out/ndf"), "--out", "-o", help="Run directory: checkpoint.pt, metrics.parquet, config.json.",
                             callback=output_dir),
    steps: int = typer.Option(8000, help="Optimizer steps.", callback=at_least_one),
    checkpoint_every: int = typer.Option(250, help="Validate, write a metrics row and a checkpoint every this many steps.",
                                         callback=at_least_one),
    categories: str = typer.Option("mug", help="Object categories of the views, comma-separated (mug,bowl,cup,bottle,can,box "
                                   "or all); two or more give the model a category head (NDF v3).", callback=category_list),
    category_weight: float = typer.Option(0.1, help="Weight of the category head's cross-entropy.", callback=non_negative),
    train_mugs: int = typer.Option(400, help="Train-split objects of each category to render views of.", callback=at_least_one),
    views_per_mug: int = typer.Option(24, help="Rendered views per training object.", callback=at_least_one),
    val_mugs: int = typer.Option(24, help="Validation objects of each category (train split, after the training ones), 8 views each.",
                                 callback=at_least_one),
    batch_mugs: int = typer.Option(16, help="Objects per batch (two views each), of any category.", callback=at_least(2)),
    alpha: float = typer.Option(0.01, help="Weight of the batch-hard shape loss (paper: 0.01).", callback=non_negative),
    shape_margin: Optional[float] = typer.Option(None, help="Hinge margin of the shape loss (default: the paper's form).",
                                                 callback=non_negative),
    code_head: str = typer.Option("gram", help="Shape code: gram (invariants of z) or norms (the paper's |z_i|)."),
    pooling: str = typer.Option("mean", help="Encoder pooling over points: max (VN max-pool) or mean (NDF's)."),
    decoder: str = typer.Option("dots", help="Occupancy decoder: frame (queries in a frame made from z) or dots (x . z_j only)."),
    lr: float = typer.Option(6e-4, help="Adam learning rate (paper: 6e-4).", callback=positive),
    lr_final: float = typer.Option(1.0, help="Cosine-decay lr to this fraction of --lr by the last step (1: constant).",
                                   callback=fraction),
    init: Optional[Path] = typer.Option(None, help="Start from these weights (e.g. the shipped ones) with a fresh optimizer.",
                                        callback=checkpoint),
    train_only: str = typer.Option("all", help="all, or refit only a fresh code_head, center_head, center_refit (see --center-refits) or decoder on the --init model's frozen encoder."),
    init_fresh: str = typer.Option("none", help="With --init: none, or decoder / code_head to start that part fresh (e.g. another size); all of it trains."),
    proxy_weight: float = typer.Option(0.0, help="Weight of the proxy identity loss on the shape codes (0: off).",
                                       callback=non_negative),
    param_weight: float = typer.Option(0.0, help="Weight of the mugs' shape-parameter regression from the codes (0: off).",
                                       callback=non_negative),
    local_points: int = typer.Option(0, help="Nearest input points each query of the frame decoder sees (0: none).",
                                     callback=non_negative),
    frame_weight: float = typer.Option(1.0, help="Weight of the frame loss: the frame decoder's axes vs the true pose (0: off).",
                                       callback=non_negative),
    center_weight: float = typer.Option(1.0, help="Weight of the center loss (the occupancy loss weighs 1).",
                                        callback=non_negative),
    decoder_width: int = typer.Option(128, help="Width of the occupancy MLP.", callback=at_least_one),
    decoder_blocks: int = typer.Option(3, help="Residual blocks of the occupancy MLP.", callback=non_negative),
    points: int = typer.Option(400, help="Points per training view (the encoder then resamples observations to this).",
                               callback=at_least(16)),
    max_distance: float = typer.Option(5.0, help="Farthest camera from the table's edge, metres (the detector encodes mugs within ~2.5 m).",
                                       callback=in_range(gt=0.2, le=10.0)),
    min_points: int = typer.Option(30, help="A view showing fewer of the mug's points is drawn again.", callback=at_least_one),
    sensor_artifacts: bool = typer.Option(False, help="Real-sensor artifacts on the views: holes, missing thin handles, flying pixels, misregistered masks."),
    up_cue: bool = typer.Option(False, help="The encoder also gets world up in the camera frame (from the pose)."),
    view_cue: bool = typer.Option(False, help="The encoder also gets the direction from the camera to the view."),
    center_head: str = typer.Option("linear", help="Center head: linear (one VN-linear channel) or gated (z weighted by its invariants)."),
    center_refits: int = typer.Option(0, help="With --train-only center_refit: gated center heads refitted and averaged into the center (NDFConfig.center_refits)."),
    up_tilt: float = typer.Option(3.0, help="With --up-cue: random tilt of the true up per training view, degrees.",
                                  callback=in_range(ge=0, lt=90)),
    gram_eps: float = typer.Option(1e-10, help="Epsilon of the batch norm on the Gram invariants (see NDFConfig).",
                                   callback=positive),
    seed: int = typer.Option(0, help="Seed of the views, the batches and the initial weights.", callback=seed_range),
    threads: int = typer.Option(2, help="Torch CPU threads (1 when another job shares the cores).",
                                callback=thread_count),
    resume: bool = typer.Option(False, help="Continue from OUT/checkpoint.pt."),
    data_dir: Optional[Path] = typer.Option(None, help="Cache of rendered views (default OUT/data).",
                                            callback=output_dir),
    log: Optional[Path] = typer.Option(None, help="Also log the metrics to this Rerun file (.rrd).",
                                       callback=output_file),
) -> None:
    """Train the NDF on rendered partial views of train-split procedural mugs or other objects (CPU)."""
    # lazy: training imports torch and open3d (seconds)
    from ndfa.training.train import TrainConfig, train
    from ndfa.training.views import ViewConfig

    names = tuple(categories.split(","))
    config = TrainConfig(
        model=NDFConfig(categories=names if len(names) > 1 else (), code_head=code_head, pooling=pooling, decoder=decoder, local_points=local_points,
                        gram_eps=gram_eps, up_cue=up_cue, view_cue=view_cue, center_head=center_head, center_refits=center_refits,
                        decoder_width=decoder_width, decoder_blocks=decoder_blocks),
        view=ViewConfig(distance_range_m=(0.2, max_distance), n_points=points, min_points=min_points,
                        artifacts=SensorArtifacts() if sensor_artifacts else None),
        categories=names, category_weight=category_weight, steps_per_epoch=checkpoint_every,
        train_mugs=train_mugs, views_per_mug=views_per_mug, val_mugs=val_mugs, batch_mugs=batch_mugs, steps=steps, lr=lr,
        lr_final_fraction=lr_final, alpha=alpha, shape_margin=shape_margin, proxy_weight=proxy_weight,
        param_weight=param_weight, up_tilt_deg=up_tilt,
        frame_weight=frame_weight, center_weight=center_weight, seed=seed, threads=threads, init_weights=str(init) if init else None,
        train_only=train_only, init_fresh=init_fresh)
    recorder = None
    if log is not None:
        import rerun as rr  # lazy: about a second to import

        recorder = rr.RecordingStream("ndfa_train")
        recorder.save(str(log))
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), TimeRemainingColumn(), console=err_console) as progress:
        task = progress.add_task("training", total=steps, info="rendering views")

        def on_step(step: int, total: int, losses: dict) -> None:
            progress.update(task, completed=step, info=f"loss {losses['loss']:.3f}")

        def on_epoch(row: dict) -> None:
            progress.console.print(
                f"epoch {row['epoch']:3d} step {row['step']:6d} "
                + "".join(f" {name} {row['train_' + name]:.3f}" for name in ("occ", "shape", "center", "proxy", "param", "category")
                          if "train_" + name in row)
                + f" | val acc {row['val_occ_accuracy']:.3f}"
                f"  center {row['val_center_median_mm']:.1f}/{row['val_center_p90_mm']:.1f} mm"
                f"  top1 {row['val_retrieval_top1']:.2f}  auc {row['val_auc']:.3f}"
                + (f"  axis {row['val_axis_error_deg']:.0f} deg" if "val_axis_error_deg" in row else "")
                + (f"  category {row['val_category_accuracy']:.3f}" if "val_category_accuracy" in row else "")
                + f"  ({row['elapsed_s'] / 60:.1f} min, CPU {row['cpu_s'] / 60:.1f} min)")
            if recorder is not None:
                import rerun as rr

                recorder.set_time("step", sequence=row["step"])
                for key, value in row.items():
                    if key not in ("epoch", "step"):
                        recorder.log(f"train/{key}", rr.Scalars(value))

        with outside_all_or_nothing():  # the checkpoints are what --resume continues from after a failure
            train(config, out, resume=resume, data_dir=data_dir, on_step=on_step, on_epoch=on_epoch)
    console.print(f"checkpoint and metrics in {out}")
