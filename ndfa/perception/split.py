"""Two mugs that touch: one DBSCAN cluster split in two by 2-means on its footprint.

DBSCAN links two mugs standing closer than its radius (`SegmentationConfig.dbscan_eps_m`) into
one cluster whose footprint is about two mugs long. Seen from above, such a pair is two blobs
along the footprint's long axis; 2-means on the horizontal positions, started at the two ends of
that axis, finds them. The caller decides whether to keep the halves (each must pass the
objectness gate, `ndfa.perception.objectness`): a single long thing split in two gives halves
that are still too flat, too tall or too thin. Pure numpy; no I/O.
"""

from __future__ import annotations

import numpy as np

_ITERATIONS = 20


def split_in_two(flat: np.ndarray) -> np.ndarray:
    """2-means on 2-D points (N, 2): a bool per point, True for the second half. Seeded at the
    points' extremes along their principal axis, so the result is deterministic."""
    centred = flat - flat.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    along = centred @ vectors[:, -1]
    centres = np.stack([flat[along.argmin()], flat[along.argmax()]])
    second = np.zeros(len(flat), dtype=bool)
    for _ in range(_ITERATIONS):
        distances = np.linalg.norm(flat[:, None, :] - centres[None], axis=2)
        updated = distances[:, 1] < distances[:, 0]
        if np.array_equal(updated, second) or updated.all() or not updated.any():
            break
        second = updated
        centres = np.stack([flat[~second].mean(axis=0), flat[second].mean(axis=0)])
    return second

