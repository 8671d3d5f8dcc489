"""Training losses of the NDF: occupancy, the paper's batch-hard shape loss, and the center loss."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def occupancy_loss(logits: torch.Tensor, occupied: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of predicted occupancy logits [B, Q] against labels [B, Q]."""
    return F.binary_cross_entropy_with_logits(logits, occupied.float())


def batch_hard_shape_loss(codes: torch.Tensor, labels: torch.Tensor, margin: float | None = None) -> torch.Tensor:
    """The paper's L_b_shape (Sec. III-B, after Hermans et al.): every observation is an anchor,
    paired with its least similar positive (same object) and most similar negative (another
    object), similarity D being the cosine of the shape codes:

        L = mean_anchors( -min_pos D(a, p) + max_neg D(a, n) )

    With `margin`, the hinge form max(0, margin - D(a, p) + D(a, n)) instead, which stops pushing
    once the negatives are `margin` below the positives. codes [M, D], labels [M] (object ids);
    every object must appear at least twice in the batch.
    """
    unit = F.normalize(codes, dim=1)
    similarity = unit @ unit.T
    same = labels[:, None] == labels[None, :]
    eye = torch.eye(len(labels), dtype=torch.bool, device=codes.device)
    positives = same & ~eye
    if not bool(positives.any(dim=1).all()):
        raise ValueError("batch-hard shape loss needs at least two observations of every object")
    hardest_positive = similarity.masked_fill(~positives, float("inf")).min(dim=1).values
    hardest_negative = similarity.masked_fill(same, float("-inf")).max(dim=1).values
    if margin is None:
        return (hardest_negative - hardest_positive).mean()
    return F.relu(margin - hardest_positive + hardest_negative).mean()


def center_loss(predicted_offset: torch.Tensor, true_offset: torch.Tensor, scale: float) -> torch.Tensor:
    """Mean Euclidean error of the predicted center offsets [B, 3] (metres), measured in the
    model's scaled units (`scale` x metres) so that it weighs like the occupancy loss."""
    return torch.linalg.vector_norm((predicted_offset - true_offset) * scale, dim=1).mean()


def proxy_identity_loss(codes: torch.Tensor, labels: torch.Tensor, proxies: torch.Tensor, scale: float) -> torch.Tensor:
    """Cosine-softmax identity loss (NormFace-style): each training mug has a learned proxy code,
    and a view's code must be more cosine-similar to its own mug's proxy than to any other's.

    Unlike a batch-hard triplet over 16 mugs, every step compares each code with all training
    mugs, which spreads the codes of different mugs over the whole sphere. codes [M, D], labels
    [M] (indices into proxies), proxies [P, D]."""
    logits = scale * F.normalize(codes, dim=1) @ F.normalize(proxies, dim=1).T
    return F.cross_entropy(logits, labels)


def parameter_loss(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error of the shape parameters [B, P] read out of the codes, against the
    mugs' standardised parameters [B, P]."""
    return F.mse_loss(predicted, target)


def frame_loss(frame_vectors: torch.Tensor, rotation_camera_object: torch.Tensor) -> torch.Tensor:
    """Align the decoder's two frame vectors [B, 3, 2] with the mug's axis (its z, base to rim)
    and its handle direction (its x), both taken from the true pose [B, 3, 3] of the view:
    1 - cosine for each, averaged. Rotating a view rotates prediction and target alike, so the
    loss is as rotation-invariant as the rest. A handle hidden from view cannot be located, and
    a handle-less mug has none; the second term then only averages out."""
    axis = F.cosine_similarity(frame_vectors[..., 0], rotation_camera_object[..., 2], dim=-1)
    handle = F.cosine_similarity(frame_vectors[..., 1], rotation_camera_object[..., 0], dim=-1)
    return (2.0 - axis - handle).mean() / 2.0


def category_loss(logits: torch.Tensor, categories: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of the category head's logits [B, C] against the views' categories [B]
    (indices into the model's `NDFConfig.categories`)."""
    return F.cross_entropy(logits, categories)
