"""Reading NDF checkpoints (`load_model`): the shipped weights or a training run's checkpoint.

Only reading happens here (the core writes no files); `ndfa.training.checkpoint` writes them.

Whatever is given as a checkpoint, a failure is one line: "FILE: not an ndfa checkpoint (why)",
with torch's own text (several lines of advice about `weights_only`, miniz internals, a list of
every missing key) summarised into the why.
"""

from __future__ import annotations

import pickle
import warnings
import zipfile
from pathlib import Path
from typing import Any

import torch

from ndfa.core.errors import ModelError
from ndfa.ndf.config import NDFConfig
from ndfa.ndf.model import NDFModel

_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's format since torch 1.6 is a zip archive


def load_model(path: str | Path) -> tuple[NDFModel, dict[str, Any]]:
    """Load a checkpoint written by `save_checkpoint`: (model in eval mode, the extra entries).

    Raises ModelError naming the file if it is missing, unreadable or not an ndfa checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: checkpoint not found")
    content = _read(path)
    if not isinstance(content, dict) or not {"config", "state_dict"} <= content.keys():
        raise _not_a_checkpoint(path, "no 'config' and 'state_dict' entries")
    if not isinstance(content["config"], dict) or not isinstance(content["state_dict"], dict):
        raise _not_a_checkpoint(path, "its 'config' and 'state_dict' are not both dictionaries")
    # Checkpoints from before the "decoder" option had the "dots" decoder, without local points.
    config: dict[str, Any] = {"decoder": "dots", "local_points": 0} | content["config"]
    try:
        model = NDFModel(NDFConfig(**config))
    except Exception as exc:  # a key NDFConfig does not have, a value it or the model cannot take
        raise _not_a_checkpoint(path, f"its model config does not fit this version of ndfa: {_first_line(exc)}") from exc
    mismatch = _weights_mismatch(model, content["state_dict"])
    if mismatch:
        raise _not_a_checkpoint(path, f"weights of another model: {mismatch}")
    try:
        model.load_state_dict(content["state_dict"])
    except (RuntimeError, TypeError) as exc:  # e.g. a dtype torch cannot copy
        raise _not_a_checkpoint(path, f"weights of another model: {_first_line(exc)}") from exc
    extra = {key: value for key, value in content.items() if key not in ("config", "state_dict")}
    return model.eval(), extra


def _read(path: Path) -> Any:
    """torch.load, weights only (a checkpoint is data; code in it is never run), with its errors
    sorted into what a user can act on."""
    with path.open("rb") as file:
        head = file.read(4)
    if not head:
        raise _not_a_checkpoint(path, "empty file")
    if head == _ZIP_MAGIC and not zipfile.is_zipfile(path):
        raise _not_a_checkpoint(path, "a truncated or corrupt torch file")
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols of files it then refuses
            warnings.simplefilter("ignore")
            return torch.load(path, weights_only=True, map_location="cpu")
    except pickle.UnpicklingError as exc:
        if head != _ZIP_MAGIC:
            raise _not_a_checkpoint(path, "not a torch file") from exc
        raise _not_a_checkpoint(path, "it holds Python objects, not only tensors and plain data; "
                                      "such files are never loaded") from exc
    except Exception as exc:  # a zip of something else, a torch file torch cannot parse, a legacy pickle
        if head == _ZIP_MAGIC:
            raise _not_a_checkpoint(path, "a zip archive, but not a torch file") from exc
        raise _not_a_checkpoint(path, "not a torch file") from exc


def _weights_mismatch(model: NDFModel, state: dict[str, Any]) -> str:
    """'' when `state` has exactly the model's tensors with their shapes, else what differs, short."""
    expected = {key: tuple(value.shape) for key, value in model.state_dict().items()}
    missing = sorted(expected.keys() - state.keys())
    unexpected = sorted(state.keys() - expected.keys())
    reshaped = sorted(key for key in expected.keys() & state.keys()
                      if not isinstance(state[key], torch.Tensor) or tuple(state[key].shape) != expected[key])
    problems = []
    if missing:
        problems.append(f"{len(missing)} of its {len(expected)} tensors missing (e.g. {missing[0]})")
    if unexpected:
        problems.append(f"{len(unexpected)} unknown tensors (e.g. {unexpected[0]})")
    if reshaped:
        key = reshaped[0]
        found = tuple(state[key].shape) if isinstance(state[key], torch.Tensor) else type(state[key]).__name__
        problems.append(f"{len(reshaped)} tensors of another shape (e.g. {key}: {found}, expected {expected[key]})")
    return "; ".join(problems)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0][:160] if text else type(exc).__name__)


def _not_a_checkpoint(path: Path, why: str) -> ModelError:
    return ModelError(f"{path}: not an ndfa checkpoint ({why})")
