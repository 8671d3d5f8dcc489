"""Model-quality figures, as plain functions of arrays: center error, shape-code retrieval and
separation, reconstruction IoU. Used by validation during training and by `ndfa ndf-eval`."""

from __future__ import annotations

import numpy as np


def cosine_similarity_matrix(codes: np.ndarray) -> np.ndarray:
    """[M, M] cosine similarities of shape codes [M, D]."""
    unit = codes / np.maximum(np.linalg.norm(codes, axis=1, keepdims=True), 1e-12)
    return unit @ unit.T


def nearest_other(codes: np.ndarray) -> np.ndarray:
    """Per observation: the index of its most cosine-similar other observation."""
    similarity = cosine_similarity_matrix(codes)
    np.fill_diagonal(similarity, -np.inf)
    return np.argmax(similarity, axis=1)


def retrieval_hits(codes: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per observation: is its most cosine-similar other observation of the same object?"""
    return labels[nearest_other(codes)] == labels


def retrieval_top1(codes: np.ndarray, labels: np.ndarray) -> float:
    """Fraction of observations whose most cosine-similar other observation shows the same object."""
    return float(np.mean(retrieval_hits(codes, labels)))


def pair_separation(codes: np.ndarray, labels: np.ndarray, threshold: float) -> dict[str, float]:
    """How well cosine similarity separates same-object from different-object pairs: the fraction
    of each above `threshold` (the detector's delta_s) and the ROC AUC over all pairs."""
    similarity = cosine_similarity_matrix(codes)
    upper = np.triu_indices(len(labels), k=1)
    values = similarity[upper]
    same = (labels[:, None] == labels[None, :])[upper]
    return {
        "same_above": float(np.mean(values[same] > threshold)),
        "different_above": float(np.mean(values[~same] > threshold)),
        "auc": roc_auc(values, same),
        "same_mean": float(values[same].mean()),
        "different_mean": float(values[~same].mean()),
    }


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve: the probability that a random positive outscores a random
    negative (ties count half), from ranks."""
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores))
    ranks[order] = np.arange(1, len(scores) + 1)
    # Average the ranks of tied scores.
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    ranks = (sums / counts)[inverse]
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def center_errors_mm(predicted: np.ndarray, true: np.ndarray) -> dict[str, float]:
    """Median and 90th percentile of the Euclidean center error, millimetres."""
    errors = np.linalg.norm(predicted - true, axis=1) * 1e3
    return {"center_median_mm": float(np.median(errors)), "center_p90_mm": float(np.percentile(errors, 90))}


def iou(predicted: np.ndarray, true: np.ndarray) -> float:
    """Intersection over union of two boolean occupancy arrays."""
    union = np.logical_or(predicted, true).sum()
    return float(np.logical_and(predicted, true).sum() / union) if union else float("nan")
