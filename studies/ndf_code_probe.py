"""Which shape parameters an NDF's shape codes encode: a ridge regression from the code to each of
the mug's `MugParams` numbers (standardised), fitted on views of training mugs and scored (R^2) on
views of held-out mugs. A parameter the codes cannot predict is one the encoder does not perceive
(or one no partial view shows), so two mugs differing only there will be confused.

    python studies/ndf_code_probe.py [WEIGHTS]        # default: the shipped weights
    # 2026-11-23, shipped weights: height 0.80, handle_top_z 0.53, rim_radius 0.37, belly 0.31, the rest < 0.2

Uses the views `ndfa train --data-dir out/ndf-data` caches (the default 400-mug cache; run that
first): 4 views of each of its training mugs to fit, its validation views (mugs 400-423) to score.
"""

import sys
from pathlib import Path

import numpy as np
import torch

from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.encoder import DEFAULT_WEIGHTS
from ndfa.training.dataset import load_dataset
from ndfa.training.shape_parameters import NUMERIC_PARAMS, shape_parameters
from ndfa.training.validate import encode_views


def main() -> None:
    torch.set_num_threads(2)
    model, _ = load_model(sys.argv[1] if len(sys.argv) > 1 else DEFAULT_WEIGHTS)
    data = Path("out/ndf-data")
    train = load_dataset(sorted(data.glob("train-947be880fb.npz"))[0])
    val = load_dataset(sorted(data.glob("val-c47010f367.npz"))[0])
    fit_rows = np.flatnonzero(train["view_id"] < 4)
    fit_codes = _codes(model, {name: values[fit_rows] if values.ndim else values for name, values in train.items()})
    fit_params = _params(train["object_index"][fit_rows])
    val_codes, val_params = _codes(model, val), _params(val["object_index"])

    mean, std = fit_params.mean(0), fit_params.std(0) + 1e-9
    design = np.c_[fit_codes, np.ones(len(fit_codes))]
    weights = np.linalg.solve(design.T @ design + np.eye(design.shape[1]), design.T @ ((fit_params - mean) / std))
    predicted = np.c_[val_codes, np.ones(len(val_codes))] @ weights
    truth = (val_params - mean) / std
    r2 = 1.0 - ((predicted - truth) ** 2).mean(0) / truth.var(0).clip(1e-9)
    for name, score in sorted(zip(NUMERIC_PARAMS, r2), key=lambda item: -item[1]):
        print(f"{name:28s} R^2 {score:6.2f}")


def _codes(model, dataset: dict) -> np.ndarray:
    with torch.inference_mode():
        return model.shape_code(encode_views(model, dataset)).numpy()


def _params(mug_indices: np.ndarray) -> np.ndarray:
    """The numeric MugParams of each view's mug (the one-hot tags are left out)."""
    return shape_parameters("train", [int(i) for i in mug_indices])[:, :len(NUMERIC_PARAMS)]


if __name__ == "__main__":
    main()
