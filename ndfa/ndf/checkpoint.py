"""Reading NDF checkpoints (`load_model`): the shipped weights or a training run's checkpoint.

Only reading happens here (the core writes no files); `ndfa.training.checkpoint` writes them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from ndfa.core.errors import ModelError
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.model import NDFModel


def load_model(path: str | Path) -> tuple[NDFModel, dict[str, Any]]:
    """Load a checkpoint written by `save_checkpoint`: (model in eval mode, the extra entries).

    Raises ModelError naming the file if it is missing, unreadable or not an ndfa checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: checkpoint not found")
    try:
        content = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as exc:  # truncated, not a torch file, or holds objects beyond plain data
        raise ModelError(f"{path}: cannot read checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(content, dict) or not {"config", "state_dict"} <= content.keys():
        raise ModelError(f"{path}: not an ndfa checkpoint (no 'config' and 'state_dict' entries)")
    try:
        # Checkpoints from before the "decoder" option had the "dots" decoder, without local points.
        model = NDFModel(NDFConfig(**({"decoder": "dots", "local_points": 0} | content["config"])))
        model.load_state_dict(content["state_dict"])
    except (TypeError, RuntimeError, ModelError) as exc:  # unknown config keys, mismatched weights
        raise ModelError(f"{path}: checkpoint does not match this model ({exc})") from exc
    extra = {key: value for key, value in content.items() if key not in ("config", "state_dict")}
    return model.eval(), extra
