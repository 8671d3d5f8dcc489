"""Writing NDF checkpoints: only training writes them (`ndfa.ndf.checkpoint.load_model` reads them).

A checkpoint is one torch file `{"config", "state_dict", **extra}`, written atomically.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from ndfa.io.atomic import atomic_path
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.model import NDFModel


def save_checkpoint(path: str | Path, model: NDFModel, config: NDFConfig, extra: dict | None = None) -> None:
    """Write `{"config", "state_dict", **extra}` with torch.save, atomically.

    `extra` (e.g. step, losses, the training config) must hold only what a weights-only load accepts
    (`load_model` uses weights_only=True): tensors, numbers, strings, lists, tuples, dicts of them.
    The file is written next to `path` and renamed over it, so a crash never leaves half a file.
    """
    extra = dict(extra or {})
    clash = {"config", "state_dict"} & extra.keys()
    if clash:
        raise ValueError(f"extra may not use the reserved keys {sorted(clash)}")
    with atomic_path(path) as temporary:
        torch.save({"config": dataclasses.asdict(config), "state_dict": model.state_dict(), **extra}, temporary)


def export_weights(checkpoint: Path, destination: Path) -> None:
    """The shippable part of a training checkpoint: model config and weights, the point count,
    the training config and its metrics; no optimizer or RNG state."""
    model, extra = load_model(checkpoint)
    keep = {key: extra[key] for key in ("n_points", "train_config", "metrics", "step", "elapsed_s") if key in extra}
    save_checkpoint(destination, model, model.config, keep)
