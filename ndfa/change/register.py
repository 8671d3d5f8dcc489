"""Sequence registration (paper Sec. IV-B): the rigid transform from the target's world frame to the
source's, from object centers matched by shape.

`rigid_transform` is the SVD (Kabsch, `ndfa.core.geometry.kabsch`) least-squares fit without scale; `ransac_registration`
draws minimal samples of three candidate pairs and keeps the transform that the most pairs
agree with (within `inlier_m`), refitted on its inliers.

What we chose, and why. The paper pairs each target object with its most shape-similar source
object and runs RANSAC once N = 6 pairs have accumulated. With mugs only, the most similar code
is often another mug of similar size, so few of those pairs are right. Here every target object
contributes up to `candidates` pairs (its most similar source objects above the shape
threshold), and a sample is only fitted when its pairwise distances agree in both sessions
(a rigid motion keeps them); one right pair per object is then enough, and the layout of the
objects, not their codes alone, picks the transform. When RANSAC runs, and when its result
replaces the current T_rel, is `ndfa.change.registrar`'s business.

A prior hypothesis (`verify_prior`) is a T_rel proposed from outside the object maps (both
sessions share one world; the sessions' scene clouds were aligned): it is not fitted to the pairs,
so the pairs only verify it, by the same inlier rule, and refine it once enough of them agree.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ndfa.core.events import RegistrationMethod
from ndfa.core.geometry import kabsch, make_pose, rotation_z


@dataclass(frozen=True)
class Registration:
    """T_rel maps target-world points into the source world: p_source = R p_target + t."""

    transform: np.ndarray       # (4, 4)
    inliers: np.ndarray         # (K,) indices into the candidate pairs that agree with it
    residual_m: float           # RMS distance of the inlier pairs after the fit
    n_pairs: int                # candidate pairs it was chosen from
    n_hypotheses: int           # minimal samples fitted
    method: RegistrationMethod = "object pairs"
    evidence: str = ""          # "... (own evidence)": the figures it was accepted on


@dataclass(frozen=True)
class RegistrationPrior:
    """A T_rel hypothesis (target world -> source world, (4, 4)) from outside the object maps."""

    method: RegistrationMethod
    transform: np.ndarray
    # Whether a RANSAC fit must agree with it: a confident prior (a shared world, a scene alignment
    # with a clear overlap) rules out chance layouts of few objects; a weak one (rooms of identical
    # tables align several ways) is only one more hypothesis.
    binding: bool = True
    # Whether it stands without object pairs: a scene alignment or shared world whose own evidence
    # is strong (`ndfa.run.scene_evidence`), accepted with fewer verifying pairs than
    # `prior_min_inliers`; `evidence` says on which figures.
    standalone: bool = False
    evidence: str = ""


def rigid_transform(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    """(4, 4) rotation + translation minimising sum |R target_i + t - source_i|^2 (Kabsch, no scale).

    target, source: (M, 3) corresponding points, M >= 3 and not all on one line.
    """
    return kabsch(target, source)[0]


def yaw_transform(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    """(4, 4) rotation about z + translation minimising sum |R target_i + t - source_i|^2.

    Both worlds are z-up (`ndfa.core.conventions`), so a turn about z and a shift is all that can
    separate them; two points (not one above the other) determine it, where Kabsch's 6-DoF fit
    needs three and tilts with the noise of near-coplanar centers.
    """
    a = target - target.mean(axis=0)
    b = source - source.mean(axis=0)
    yaw = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    rotation = rotation_z(float(yaw))
    return make_pose(rotation, source.mean(axis=0) - rotation @ target.mean(axis=0))


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """`points` (N, 3) moved by `transform` (4, 4), or by each of a stack (H, 4, 4): (H, N, 3)."""
    moved: np.ndarray = points @ np.swapaxes(transform[..., :3, :3], -1, -2) + transform[..., None, :3, 3]
    return moved


def ransac_registration(
    pairs: list[tuple[int, int]],
    target_centers: dict[int, np.ndarray],
    source_centers: dict[int, np.ndarray],
    inlier_m: float,
    max_hypotheses: int = 2000,
    seed: int = 0,
) -> Registration | None:
    """The best-supported T_rel from candidate (target id, source id) pairs, or None if none fits.

    Hypotheses: three target objects and one candidate source object for each, such that the
    three pairwise center distances agree in both sessions within 2 * inlier_m (a rigid motion
    keeps them). Triples of target objects are tried exhaustively when few, else drawn at random;
    for each, all agreeing candidate triples are fitted, up to `max_hypotheses` fits in all.
    A pair counts as an inlier when its transformed target center is within `inlier_m` of its
    source center; each target object and each source object counts once (its closest pair).
    The winner (most inliers, then lowest residual) is refitted on its inliers.
    """
    if len(pairs) < 3:
        return None
    t = np.array([target_centers[a] for a, _ in pairs], dtype=np.float64)
    s = np.array([source_centers[b] for _, b in pairs], dtype=np.float64)
    target_ids = np.array([a for a, _ in pairs])
    source_ids = np.array([b for _, b in pairs])
    by_target = {a: np.flatnonzero(target_ids == a) for a in np.unique(target_ids)}
    if len(by_target) < 3:
        return None
    rng = np.random.default_rng(seed)
    # Center distances between the pairs' objects, in each session (a rigid motion keeps them).
    target_distances = np.linalg.norm(t[:, None] - t[None], axis=-1)
    source_distances = np.linalg.norm(s[:, None] - s[None], axis=-1)
    samples = np.array(list(itertools.islice(
        (sample for triple in _target_triples(sorted(by_target), max_hypotheses, rng)
         for sample in _agreeing_samples(triple, by_target, target_distances, source_distances, source_ids, 2 * inlier_m)),
        max_hypotheses)), dtype=int).reshape(-1, 3)
    if len(samples) == 0:
        return None
    transforms, _ = kabsch(t[samples], s[samples])  # every hypothesis at once
    errors = _errors(transforms, t, s)
    # A hypothesis' inliers (one pair per object) are at most its pairs within inlier_m: score the
    # hypotheses in that order and stop where none left can reach the best. The winner: most
    # inliers, then lowest residual, then the first drawn.
    within = (errors <= inlier_m).sum(axis=1)
    best: tuple[int, float, int] | None = None
    best_inliers = np.zeros(0, dtype=int)
    for h in np.argsort(-within, kind="stable"):
        if best is not None and within[h] < best[0]:
            break
        inliers = _unique_inliers(errors[h], target_ids, source_ids, inlier_m)
        key = (len(inliers), -_rms(transforms[h], t[inliers], s[inliers]), -int(h))
        if best is None or key > best:
            best, best_inliers = key, inliers
    if best is None or best[0] < 3:
        return None
    inliers = best_inliers
    transform = rigid_transform(t[inliers], s[inliers])
    inliers = _unique_inliers(_errors(transform, t, s), target_ids, source_ids, inlier_m)
    if len(inliers) >= 3:
        transform = rigid_transform(t[inliers], s[inliers])
    return Registration(transform, inliers, _rms(transform, t[inliers], s[inliers]), len(pairs), len(samples))


def _target_triples(target_ids: list[int], max_triples: int,
                    rng: np.random.Generator) -> Iterator[tuple[int, ...]]:
    n = len(target_ids)
    if n * (n - 1) * (n - 2) // 6 <= max_triples:
        yield from itertools.combinations(target_ids, 3)
        return
    for _ in range(max_triples):
        yield tuple(rng.choice(target_ids, size=3, replace=False))


def _agreeing_samples(triple: tuple[int, ...], by_target: dict[int, np.ndarray], target_distances: np.ndarray,
                      source_distances: np.ndarray, source_ids: np.ndarray, tolerance: float) -> Iterator[list[int]]:
    """Pair-index triples (one candidate pair per target object of `triple`) whose center
    distances agree between the sessions, and whose source objects are distinct."""
    a, b, c = (by_target[i] for i in triple)
    d_ab, d_ac, d_bc = (target_distances[x[0], y[0]] for x, y in ((a, b), (a, c), (b, c)))
    ab = np.abs(source_distances[np.ix_(a, b)] - d_ab) <= tolerance
    for i, j in zip(*np.nonzero(ab)):
        ok = (np.abs(source_distances[c, a[i]] - d_ac) <= tolerance) & (np.abs(source_distances[c, b[j]] - d_bc) <= tolerance)
        for k in np.flatnonzero(ok):
            sample = [a[i], b[j], c[k]]
            if len(set(source_ids[sample])) == 3:
                yield sample


def _errors(transform: np.ndarray, t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Each pair's registration error (P,), or per transform of a stack (H, P)."""
    error: np.ndarray = np.linalg.norm(apply(transform, t) - s, axis=-1)
    return error


def _unique_inliers(error: np.ndarray, target_ids: np.ndarray, source_ids: np.ndarray, inlier_m: float) -> np.ndarray:
    """Inlier pair indices from each pair's registration error, at most one per target object and
    per source object (the closest)."""
    used_target, used_source, chosen = set(), set(), []
    for index in np.argsort(error, kind="stable"):
        if error[index] > inlier_m:
            break
        if target_ids[index] in used_target or source_ids[index] in used_source:
            continue
        used_target.add(target_ids[index])
        used_source.add(source_ids[index])
        chosen.append(index)
    return np.array(sorted(chosen), dtype=int)


def _rms(transform: np.ndarray, t: np.ndarray, s: np.ndarray) -> float:
    if len(t) == 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum((apply(transform, t) - s) ** 2, axis=1))))


def verify_prior(
    prior: RegistrationPrior,
    pairs: list[tuple[int, int]],
    target_centers: dict[int, np.ndarray],
    source_centers: dict[int, np.ndarray],
    inlier_m: float,
    support_m: float,
) -> Registration:
    """The prior, verified and refined by candidate (target id, source id) pairs.

    A prior carries its own error (a shared world: the poses'; a scene alignment: its voxels and
    the drift of the poses it fused), so the pairs within `support_m` of where it puts them
    support it; with two or more, it is corrected by the turn about z and shift that best fits
    them (`yaw_transform`), kept when it has at least the prior's own inliers. Its inliers are
    then counted by RANSAC's rule (within `inlier_m`, each object once).
    """
    transform = np.asarray(prior.transform, dtype=np.float64)
    if not pairs:
        return Registration(transform, np.zeros(0, dtype=int), float("nan"), 0, 1, prior.method)
    t = np.array([target_centers[a] for a, _ in pairs], dtype=np.float64)
    s = np.array([source_centers[b] for _, b in pairs], dtype=np.float64)
    target_ids = np.array([a for a, _ in pairs])
    source_ids = np.array([b for _, b in pairs])
    error = _errors(transform, t, s)
    inliers = _unique_inliers(error, target_ids, source_ids, inlier_m)
    support = _unique_inliers(error, target_ids, source_ids, support_m)
    if len(support) >= 2:
        refined = yaw_transform(apply(transform, t[support]), s[support]) @ transform
        refined_inliers = _unique_inliers(_errors(refined, t, s), target_ids, source_ids, inlier_m)
        if len(refined_inliers) >= len(inliers):
            transform, inliers = refined, refined_inliers
    return Registration(transform, inliers, _rms(transform, t[inliers], s[inliers]), len(pairs), 1, prior.method)
