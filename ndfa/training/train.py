"""`ndfa train`: fit the NDF on partial views of train-split procedural mugs, on the CPU.

The loop, top to bottom: render (or load the cached) training and validation views; then for each
step draw a batch of mugs with two views each, centre every view on its points' mean, and
minimise

    L = L_occ + alpha * L_b_shape + w_center * L_center [+ w_proxy * L_proxy + w_frame * L_frame
                                                          + w_param * L_param]

(the paper's objective plus an equivariant center head, and optionally an identity loss over all
training mugs, the alignment of the decoder's object frame with the true pose, and a regression
of each mug's shape parameters from its code; `losses.py`). Every
`steps_per_epoch` steps: validate, append a metrics row, save a checkpoint (model, optimizer,
step, RNG state), so that an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import polars as pl
import torch

from ndfa.core.errors import ModelError
from ndfa.io.atomic import write_parquet
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.model import NDFModel
from ndfa.training.batches import batch_rows, sample_batch, sample_rows
from ndfa.training.checkpoint import save_checkpoint
from ndfa.training.dataset import generate_views, load_dataset, write_dataset
from ndfa.training.losses import (
    batch_hard_shape_loss,
    center_loss,
    frame_loss,
    occupancy_loss,
    parameter_loss,
    proxy_identity_loss,
)
from ndfa.training.shape_parameters import shape_parameters
from ndfa.training.validate import encode_views, mean_codes, validate
from ndfa.training.views import ViewConfig


@dataclass(frozen=True)
class TrainConfig:
    model: NDFConfig = field(default_factory=NDFConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    train_mugs: int = 400            # train-split mug indices [0, train_mugs)
    views_per_mug: int = 24
    val_mugs: int = 24               # held-out train-split mugs, right after the training ones
    val_views_per_mug: int = 8
    batch_mugs: int = 16             # mugs per batch, two views each
    steps: int = 8000
    steps_per_epoch: int = 250       # validation, metrics row and checkpoint every epoch
    lr: float = 6e-4                 # the paper's Adam learning rate
    lr_final_fraction: float = 1.0   # cosine decay of lr to this fraction at the last step (1: constant, the paper's)
    init_weights: str | None = None  # start from this checkpoint's weights (a fresh optimizer), e.g. to continue a shipped model
    train_only: str = "all"          # "all", or refit only a fresh "code_head", "center_head", "center_refit" or "decoder" on init_weights' frozen encoder
    init_fresh: str = "none"         # "none", or "decoder" / "code_head": that part starts fresh (e.g. another size), the rest from init_weights; all of it trains
    alpha: float = 0.01              # the paper's shape-loss weight
    shape_margin: float | None = None  # None: the paper's loss; a number: hinge with this margin
    center_weight: float = 1.0
    frame_weight: float = 1.0        # weight of the frame loss (the "frame" decoder's axis and handle); 0: off
    proxy_weight: float = 0.0        # weight of the proxy (cosine-softmax) identity loss on the codes; 0: off
    proxy_scale: float = 16.0        # its logit scale: cosine similarities are multiplied by this
    param_weight: float = 0.0        # weight of the shape-parameter regression from the code (`shape_parameters`); 0: off
    up_tilt_deg: float = 3.0         # with the model's up cue: std. dev. of the random tilt of the true up per view (pose and table errors)
    shape_threshold: float = 0.9     # delta_s, for the validation figures
    seed: int = 0
    threads: int = 2


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

    model = _initial_model(config)
    # A trained model's codes seed the proxies; a fresh head's would be noise.
    heads = TrainingHeads(config, model, train_set if config.init_weights and config.train_only != "code_head" else None)
    optimizer = torch.optim.Adam(_trainable(model, heads, config), lr=config.lr)
    rng = np.random.default_rng([config.seed, 100])
    step, rows, elapsed = 0, [], 0.0
    checkpoint_path = out_dir / "checkpoint.pt"
    if resume and checkpoint_path.exists():
        model, extra = load_model(checkpoint_path)
        # A run may be resumed longer or with other threads; anything else must match.
        if _without(extra.get("train_config", {}), RESUMABLE) != _without(_jsonable(config), RESUMABLE):
            raise ModelError(f"{checkpoint_path}: was trained with other settings; use another --out or no --resume")
        heads.load_state_dict(extra["training_heads"])
        optimizer = torch.optim.Adam(_trainable(model, heads, config), lr=config.lr)
        optimizer.load_state_dict(extra["optimizer"])
        rng.bit_generator.state = json.loads(extra["rng_state"])
        torch.set_rng_state(extra["torch_rng_state"])
        step, rows, elapsed = extra["step"], json.loads(extra["metrics"]), extra["elapsed_s"]
    (out_dir / "config.json").write_text(json.dumps(_jsonable(config), indent=2))

    frozen_z = encode_views(model, train_set) if config.train_only != "all" else None
    losses: list[dict] = []
    started = time.perf_counter() - elapsed
    while step < config.steps:
        model.train()
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step)
        if frozen_z is None:
            terms = _loss_terms(model, sample_batch(train_set, config.batch_mugs, rng), config, heads)
        elif config.train_only == "code_head":
            picked = torch.from_numpy(batch_rows(train_set, config.batch_mugs, rng))
            labels = torch.from_numpy(train_set["mug_index"].astype(np.int64))[picked]
            terms = _shape_terms(model.shape_code(frozen_z[picked]), labels, config, heads)
        elif config.train_only in ("center_head", "center_refit"):
            picked = torch.from_numpy(batch_rows(train_set, config.batch_mugs, rng))
            centroid = torch.from_numpy(train_set["points"][picked.numpy()]).mean(dim=1)
            target = torch.from_numpy(train_set["center"][picked.numpy()]) - centroid
            terms = {"center": _center_term(model, frozen_z[picked], target, config)}
        else:
            picked = batch_rows(train_set, config.batch_mugs, rng)
            terms = _decoder_terms(model, frozen_z[torch.from_numpy(picked)], sample_rows(train_set, picked), config)
        weights = {"occ": 1.0, "shape": config.alpha, "center": config.center_weight, "proxy": config.proxy_weight,
                   "frame": config.frame_weight, "param": config.param_weight}
        loss = sum(weights[name] * term for name, term in terms.items())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        losses.append({k: v.item() for k, v in terms.items()} | {"loss": loss.item()})
        if on_step is not None:
            on_step(step, config.steps, losses[-1])
        if step % config.steps_per_epoch == 0 or step == config.steps:
            row = {"epoch": len(rows) + 1, "step": step, "elapsed_s": time.perf_counter() - started}
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


class TrainingHeads(torch.nn.Module):
    """Parameters that only training uses and the shipped model leaves out: one learned proxy code
    per training mug (the proxy loss) and a linear read-out of the mugs' shape parameters from the
    code (the parameter loss), each present only when its loss weight is above 0."""

    def __init__(self, config: TrainConfig, model: NDFModel, train_set: dict[str, np.ndarray] | None = None) -> None:
        super().__init__()
        code_dim = model.config.code_dim_out
        self.proxies = None
        if config.proxy_weight > 0:
            # A trained model's proxies start at its mean code per mug: random ones would pull
            # every code toward noise until they were learnt (measured: the loss stayed near
            # chance, log(400), for 1,000 steps of fine-tuning at lr 2e-4).
            initial = torch.randn(config.train_mugs, code_dim) if train_set is None else mean_codes(model, train_set, config.train_mugs)
            self.proxies = torch.nn.Parameter(initial.clone())
        self.param_readout = None
        if config.param_weight > 0:
            table = torch.from_numpy(shape_parameters("train", list(range(config.train_mugs))))
            # Standardised over the training mugs, so that centimetres and fractions weigh alike.
            self.register_buffer("param_targets", (table - table.mean(0)) / table.std(0).clamp_min(1e-6))
            self.param_readout = torch.nn.Linear(code_dim, table.shape[1])

    def losses(self, codes: torch.Tensor, mug_index: torch.Tensor, config: TrainConfig) -> dict[str, torch.Tensor]:
        terms = {}
        if self.proxies is not None:
            terms["proxy"] = proxy_identity_loss(codes, mug_index, self.proxies, config.proxy_scale)
        if self.param_readout is not None:
            terms["param"] = parameter_loss(self.param_readout(codes), self.param_targets[mug_index])
        return terms


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
    } | _shape_terms(out["shape_code"], batch["mug_index"], config, heads) | (
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


def _shape_terms(codes: torch.Tensor, mug_index: torch.Tensor, config: TrainConfig, heads: TrainingHeads) -> dict[str, torch.Tensor]:
    return {"shape": batch_hard_shape_loss(codes, mug_index, config.shape_margin)} | heads.losses(codes, mug_index, config)


def _trainable(model: NDFModel, heads: TrainingHeads, config: TrainConfig) -> list[torch.nn.Parameter]:
    parts = {"all": model, "code_head": model.gram_code, "center_head": model.center_head, "center_refit": model.center_refit,
             "decoder": model.decoder}
    return list(parts[config.train_only].parameters()) + list(heads.parameters())


def _initial_model(config: TrainConfig) -> NDFModel:
    """A fresh model, or `init_weights`' weights in this run's model; with `train_only`, the part
    to refit starts fresh (the others must fit)."""
    model = NDFModel(config.model)
    if config.train_only not in ("all", "code_head", "center_head", "center_refit", "decoder"):
        raise ModelError(f"train_only must be all, code_head, center_head, center_refit or decoder, not {config.train_only!r}")
    if config.train_only == "center_refit" and not config.model.center_refits:
        raise ModelError("refitting the center needs center_refits > 0 (how many heads to average)")
    if config.train_only == "all" and config.model.center_refits:
        raise ModelError("refitted center heads are fitted with train_only center_refit, on a trained model")
    if config.init_weights is None:
        if config.train_only != "all":
            raise ModelError(f"refitting the {config.train_only} needs --init weights")
        return model
    if config.train_only == "code_head" and config.model.code_head != "gram":
        raise ModelError("refitting the code head needs the gram code head")
    if config.init_fresh not in ("none", "code_head", "decoder"):
        raise ModelError(f"init_fresh must be none, code_head or decoder, not {config.init_fresh!r}")
    part = config.train_only if config.train_only != "all" else config.init_fresh
    fresh = {"all": "", "none": "", "code_head": "gram_code.", "center_head": "center_head.", "center_refit": "center_refit.",
             "decoder": "decoder."}[part]
    initial = load_model(config.init_weights)[0].state_dict()
    kept = {name: value for name, value in initial.items() if not (fresh and name.startswith(fresh))}
    try:
        missing, unexpected = model.load_state_dict(kept, strict=False)
    except RuntimeError as exc:
        raise ModelError(f"{config.init_weights}: its weights do not fit this run's model ({exc})") from exc
    if unexpected or any(not (fresh and name.startswith(fresh)) for name in missing):
        raise ModelError(f"{config.init_weights}: its weights do not fit this run's model "
                         f"(missing {missing[:5]}, unexpected {unexpected[:5]})")
    return model


def _datasets(config: TrainConfig, data_dir: Path) -> tuple[dict, dict]:
    train_indices = list(range(config.train_mugs))
    val_indices = list(range(config.train_mugs, config.train_mugs + config.val_mugs))
    return (
        _cached_views(data_dir, "train", train_indices, config.views_per_mug, config.seed, config.view),
        _cached_views(data_dir, "val", val_indices, config.val_views_per_mug, config.seed + 1, config.view),
    )


def _cached_views(data_dir: Path, name: str, indices: list[int], views_per_mug: int, seed: int, view: ViewConfig) -> dict:
    key = json.dumps({"indices": [indices[0], indices[-1]], "views": views_per_mug, "seed": seed,
                      "view": _jsonable(view)}, sort_keys=True)
    path = data_dir / f"{name}-{hashlib.sha1(key.encode()).hexdigest()[:10]}.npz"
    if not path.exists():
        data_dir.mkdir(parents=True, exist_ok=True)
        write_dataset(path, generate_views("train", indices, views_per_mug, seed, view))
    return load_dataset(path)


RESUMABLE = ("steps", "threads")  # TrainConfig fields a resumed run may change


def _without(config: dict, keys: tuple[str, ...]) -> dict:
    return {k: v for k, v in config.items() if k not in keys}


def _jsonable(value):
    """Dataclasses (nested) as JSON-compatible data, for configs stored beside results."""
    return json.loads(json.dumps(dataclasses.asdict(value), default=str))
