"""`ndfa train`: fit the NDF on partial views of train-split procedural mugs (or objects of
several categories: `TrainConfig.categories`), on the CPU.

The loop, top to bottom: render (or load the cached) training and validation views; then for each
step draw a batch of mugs with two views each, centre every view on its points' mean, and
minimise

    L = L_occ + alpha * L_b_shape + w_center * L_center [+ w_proxy * L_proxy + w_frame * L_frame
                                                          + w_param * L_param + w_category * L_category]

(the paper's objective plus an equivariant center head, and optionally an identity loss over all
training mugs, the alignment of the decoder's object frame with the true pose, and a regression
of each mug's shape parameters from its code, and with several categories the cross-entropy of
the category head on the code; `losses.py`). Every
`steps_per_epoch` steps: validate, append a metrics row, save a checkpoint (model, optimizer,
step, RNG state), so that an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import polars as pl
import torch

from ndfa.core.errors import ModelError
from ndfa.io.atomic import write_parquet
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.model import NDFModel
from ndfa.training.batches import batch_labels, batch_rows, sample_batch, sample_rows
from ndfa.training.checkpoint import save_checkpoint
from ndfa.training.dataset import generate_views, load_dataset, write_dataset
from ndfa.training.losses import center_loss, frame_loss, occupancy_loss
from ndfa.training.train_config import TrainConfig
from ndfa.training.trained_parts import TrainingHeads, initial_model, shape_terms, trainable
from ndfa.training.validate import encode_views, validate
from ndfa.training.views import ViewConfig

__all__ = ["TrainConfig", "learning_rate", "tilted", "train"]


def train(
    config: TrainConfig,
    out_dir: Path,
    resume: bool = False,
    data_dir: Path | None = None,
    on_step: Callable[[int, int, dict], None] | None = None,
    on_epoch: Callable[[dict], None] | None = None,
) -> pl.DataFrame:
    """Train into `out_dir` (checkpoint.pt, metrics.parquet, config.json); returns the metrics.

    `data_dir` caches rendered views (default `out_dir/data`); a cache is reused only when it
    was made with the same view settings, mugs and seed.

    With `train_only` "code_head", "center_head", "center_refit" or "decoder", the model of `init_weights` keeps everything else
    and only a fresh part is fitted, to the frozen encoder's z of every training view, computed
    once. The code head then costs about a millisecond a step, so it can see many mugs per batch
    (`batch_mugs`) and many steps in minutes; only the shape losses apply. The center head, as
    cheap, learns with the center loss alone; "center_refit" fits `NDFConfig.center_refits` new heads
    whose mean becomes the center while the decoder keeps the center head. The decoder (of this
    run's model config, e.g. another decoder kind) learns with the occupancy and frame losses.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    train_set, val_set = _datasets(config, Path(data_dir or out_dir / "data"))

    model = initial_model(config)
    # A trained model's codes seed the proxies; a fresh head's would be noise.
    heads = TrainingHeads(config, model, train_set if config.init_weights and config.train_only != "code_head" else None)
    optimizer = torch.optim.Adam(trainable(model, heads, config), lr=config.lr)
    rng = np.random.default_rng([config.seed, 100])
    step, rows, elapsed, cpu = 0, [], 0.0, 0.0
    checkpoint_path = out_dir / "checkpoint.pt"
    if resume and checkpoint_path.exists():
        model, extra = load_model(checkpoint_path)
        # A run may be resumed longer or with other threads; anything else must match.
        # Settings added since the checkpoint was written take their defaults.
        stored = _with_defaults(extra.get("train_config", {}), _jsonable(TrainConfig()))
        if _without(stored, RESUMABLE) != _without(_jsonable(config), RESUMABLE):
            raise ModelError(f"{checkpoint_path}: was trained with other settings; use another --out or no --resume")
        heads.load_state_dict(extra["training_heads"])
        optimizer = torch.optim.Adam(trainable(model, heads, config), lr=config.lr)
        optimizer.load_state_dict(extra["optimizer"])
        rng.bit_generator.state = json.loads(extra["rng_state"])
        torch.set_rng_state(extra["torch_rng_state"])
        step, rows, elapsed = extra["step"], json.loads(extra["metrics"]), extra["elapsed_s"]
        cpu = rows[-1].get("cpu_s", 0.0) if rows else 0.0
    (out_dir / "config.json").write_text(json.dumps(_jsonable(config), indent=2))

    frozen_z = encode_views(model, train_set) if config.train_only != "all" else None
    losses: list[dict] = []
    # Wall time, and this process's CPU time (all its threads; not the rendering workers'): on a
    # loaded machine the CPU time per step is what a quiet one would take with one thread.
    started, cpu_started = time.perf_counter() - elapsed, time.process_time() - cpu
    while step < config.steps:
        model.train()
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step)
        if frozen_z is None:
            terms = _loss_terms(model, sample_batch(train_set, config.batch_mugs, rng), config, heads)
        elif config.train_only == "code_head":
            picked = batch_rows(train_set, config.batch_mugs, rng)
            terms = shape_terms(model, model.shape_code(frozen_z[torch.from_numpy(picked)]), batch_labels(train_set, picked),
                                config, heads)
        elif config.train_only in ("center_head", "center_refit"):
            picked = torch.from_numpy(batch_rows(train_set, config.batch_mugs, rng))
            centroid = torch.from_numpy(train_set["points"][picked.numpy()]).mean(dim=1)
            target = torch.from_numpy(train_set["center"][picked.numpy()]) - centroid
            terms = {"center": _center_term(model, frozen_z[picked], target, config)}
        else:
            picked = batch_rows(train_set, config.batch_mugs, rng)
            terms = _decoder_terms(model, frozen_z[torch.from_numpy(picked)], sample_rows(train_set, picked), config)
        weights = {"occ": 1.0, "shape": config.alpha, "center": config.center_weight, "proxy": config.proxy_weight,
                   "frame": config.frame_weight, "param": config.param_weight, "category": config.category_weight}
        loss = sum(weights[name] * term for name, term in terms.items())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        losses.append({k: v.item() for k, v in terms.items()} | {"loss": loss.item()})
        if on_step is not None:
            on_step(step, config.steps, losses[-1])
        if step % config.steps_per_epoch == 0 or step == config.steps:
            row = {"epoch": len(rows) + 1, "step": step, "elapsed_s": time.perf_counter() - started,
                   "cpu_s": time.process_time() - cpu_started}
            row |= {f"train_{k}": float(np.mean([step_losses[k] for step_losses in losses])) for k in losses[0]}
            row |= {f"val_{k}": v for k, v in validate(model, val_set, config.shape_threshold).items()}
            rows.append(row)
            losses = []
            save_checkpoint(checkpoint_path, model, config.model, {
                "train_config": _jsonable(config),
                "n_points": config.view.n_points,
                "optimizer": optimizer.state_dict(),
                "rng_state": json.dumps(rng.bit_generator.state),
                "torch_rng_state": torch.get_rng_state(),
                "step": step,
                "metrics": json.dumps(rows),
                "elapsed_s": row["elapsed_s"],
                "training_heads": heads.state_dict(),
            })
            metrics = pl.DataFrame(rows)
            write_parquet(metrics, out_dir / "metrics.parquet")
            if on_epoch is not None:
                on_epoch(row)
    return pl.DataFrame(rows)


def learning_rate(config: TrainConfig, step: int) -> float:
    """lr at `step`: cosine from `lr` down to `lr * lr_final_fraction` over the run's steps.
    Decaying at the end lets the last steps settle instead of jittering at the full step size."""
    progress = min(step / max(config.steps - 1, 1), 1.0)
    fraction = config.lr_final_fraction + (1.0 - config.lr_final_fraction) * 0.5 * (1.0 + np.cos(np.pi * progress))
    return float(config.lr * fraction)


def _loss_terms(model: NDFModel, batch: dict[str, torch.Tensor], config: TrainConfig,
                heads: TrainingHeads) -> dict[str, torch.Tensor]:
    # The model sees each view centred on its points' mean (the translation part of SE(3)
    # equivariance); queries and the true center are expressed relative to the same mean.
    centroid = batch["points"].mean(dim=1, keepdim=True)
    # Tilted only for a model that reads up: drawing noise otherwise would shift the torch RNG
    # stream of runs without the cue.
    up = tilted(batch["rotation"][..., 2], config.up_tilt_deg) if config.model.up_cue else None
    out = model(batch["points"] - centroid, batch["queries"] - centroid, up, centroid[:, 0])
    return {
        "occ": occupancy_loss(out["occupancy_logits"], batch["occupancy"]),
        "center": _center_term(model, out["z"], batch["center"] - centroid[:, 0], config),
    } | shape_terms(model, out["shape_code"], batch, config, heads) | (
        {"frame": frame_loss(out["frame_vectors"], batch["rotation"])}
        if "frame_vectors" in out and config.frame_weight > 0 else {})


def _center_term(model: NDFModel, z: torch.Tensor, target: torch.Tensor, config: TrainConfig) -> torch.Tensor:
    """The center loss of the head being fitted; of each refitted head, averaged, so that they
    learn apart (`NDFConfig.center_refits`)."""
    offsets = model.center_offset_members(z) if config.train_only == "center_refit" else model.frame_origin(z)[None]
    return torch.stack([center_loss(offset, target, config.model.input_scale) for offset in offsets]).mean()


def tilted(up: torch.Tensor, std_deg: float) -> torch.Tensor:
    """Unit vectors `[B, 3]` tilted from `up` by random small angles (about `std_deg` per axis):
    the up the detector derives from a camera pose is off by the pose's error and the table's slope."""
    noisy = up + torch.randn_like(up) * np.radians(std_deg)
    return torch.nn.functional.normalize(noisy, dim=-1)


def _decoder_terms(model: NDFModel, z: torch.Tensor, batch: dict[str, torch.Tensor], config: TrainConfig) -> dict[str, torch.Tensor]:
    centroid = batch["points"].mean(dim=1, keepdim=True)
    logits = model.occupancy_logits(z, batch["queries"] - centroid, batch["points"] - centroid)
    frame_vectors = model.frame_vectors(z)
    return {"occ": occupancy_loss(logits, batch["occupancy"])} | (
        {"frame": frame_loss(frame_vectors, batch["rotation"])} if frame_vectors is not None and config.frame_weight > 0 else {})


def _datasets(config: TrainConfig, data_dir: Path) -> tuple[dict, dict]:
    train_indices = list(range(config.train_mugs))
    val_indices = list(range(config.train_mugs, config.train_mugs + config.val_mugs))
    return (
        _cached_views(data_dir, "train", train_indices, config.views_per_mug, config.seed, config.view, config.categories),
        _cached_views(data_dir, "val", val_indices, config.val_views_per_mug, config.seed + 1, config.view, config.categories),
    )


def _cached_views(data_dir: Path, name: str, indices: list[int], views_per_mug: int, seed: int, view: ViewConfig,
                  categories: tuple[str, ...]) -> dict:
    # Mugs alone keep the key they had before there were categories, so their caches still serve.
    key = json.dumps({"indices": [indices[0], indices[-1]], "views": views_per_mug, "seed": seed,
                      "view": _jsonable(view)} | ({} if categories == ("mug",) else {"categories": list(categories)}),
                     sort_keys=True)
    path = data_dir / f"{name}-{hashlib.sha1(key.encode()).hexdigest()[:10]}.npz"
    if not path.exists():
        data_dir.mkdir(parents=True, exist_ok=True)
        write_dataset(path, generate_views("train", indices, views_per_mug, seed, view, categories=categories))
    return load_dataset(path)


RESUMABLE = ("steps", "threads", "steps_per_epoch")  # TrainConfig fields a resumed run may change


def _without(config: dict, keys: tuple[str, ...]) -> dict:
    return {k: v for k, v in config.items() if k not in keys}


def _with_defaults(stored: dict, defaults: dict) -> dict:
    """`stored` with what it lacks of `defaults` (nested dicts alike): settings added since."""
    merged = dict(stored)
    for key, value in defaults.items():
        if key not in merged:
            merged[key] = value
        elif isinstance(value, dict) and isinstance(merged[key], dict):
            merged[key] = _with_defaults(merged[key], value)
    return merged


def _jsonable(value):
    """Dataclasses (nested) as JSON-compatible data, for configs stored beside results."""
    return json.loads(json.dumps(dataclasses.asdict(value), default=str))
