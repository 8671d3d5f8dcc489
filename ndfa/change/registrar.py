"""T_rel over a target pass (paper Sec. IV-B): when to estimate it, the estimate, and the target
centers it registers into the source world.

Until T_rel exists, an estimate is tried when a target object is created and otherwise every
`retry_frames` frames (the codes and centers of known objects still improve); after that, a new
target object triggers a re-estimate while T_rel has fewer than `enough_inliers` inliers, and the
new estimate replaces it only with more inliers (decisions already made used it). The estimate
itself is `ndfa.change.register.ransac_registration` on shape-matched (target, source) pairs.

Prior hypotheses (`add_prior`: the sessions share one world, or their scene clouds were aligned)
are scored at every attempt by the same pairs (`ndfa.change.register.verify_prior`), also before
there are N of them: with few objects (two mugs on a table) RANSAC never gets its N, but a prior
that two pairs agree with is a T_rel. Each candidate must pass its own bar (RANSAC
`RansacConfig.min_inliers`; a prior `PriorConfig.min_inliers`, or RANSAC's for a scene alignment
whose own evidence is weak; and a RANSAC fit must agree with a prior where there is one); the one
with most inliers wins, RANSAC's on a tie. A standalone prior (a scene alignment or shared world
whose own evidence is strong, `RegistrationPrior.standalone`) passes with fewer pairs, as "scene (own
evidence)" or "shared world (own evidence)": the objects are then tested against it, and pairs that
confirm it later replace it.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable

import numpy as np

from ndfa.change.associate import Association, SessionMap, cosine_similarity
from ndfa.change.config import DetectorConfig
from ndfa.change.register import Registration, RegistrationPrior, apply, ransac_registration, verify_prior
from ndfa.change.tree import Region
from ndfa.core.events import RegistrationEvent, RegistrationMethod

# A standalone prior accepted without confirming pairs, named by what proposed it.
OWN_EVIDENCE: dict[RegistrationMethod, RegistrationMethod] = {
    "scene alignment": "scene (own evidence)", "shared world": "shared world (own evidence)"}


class RegisteredCenters:
    """Every target object's center mapped into the source world with one T_rel (row i: object i).

    Invalidation: a row is valid while neither T_rel nor its object's center has changed. A new
    T_rel recomputes every row; an object whose center changed (`stale`) gets its row recomputed,
    alone, at the next query.
    """

    def __init__(self) -> None:
        self._rows = np.zeros((0, 3))
        self._transform: np.ndarray | None = None  # the T_rel the rows were computed with
        self._stale: set[int] = set()

    def stale(self, object_ids: Iterable[int]) -> None:
        """These objects were created or their centers moved."""
        self._stale.update(object_ids)

    def get(self, transform: np.ndarray, target: SessionMap) -> np.ndarray:
        n = len(target.objects)  # object ids are 0 .. n-1
        if self._transform is transform:
            for object_id in sorted(self._stale):
                row = apply(transform, target.objects[object_id].center_world[None])  # (1, 3): a batch may round differently
                if object_id < len(self._rows):
                    self._rows[object_id] = row[0]
                elif object_id == len(self._rows):
                    self._rows = np.vstack([self._rows, row])
        if self._transform is not transform or len(self._rows) != n:
            centers = np.array([target.objects[i].center_world for i in range(n)]).reshape(n, 3)
            self._rows = apply(transform, centers)
            self._transform = transform
        self._stale.clear()
        return self._rows


class Registrar:
    """T_rel between the maps `source` and `target` as the target pass fills the latter."""

    def __init__(self, config: DetectorConfig, source: SessionMap, target: SessionMap) -> None:
        self.config = config.registration
        self.ransac, self.prior_config = config.ransac, config.priors
        self.shape_similarity = config.association.shape_similarity
        self.source, self.target = source, target
        self.registration: Registration | None = None
        self.priors: list[RegistrationPrior] = []
        self.centers = RegisteredCenters()
        self._last_try_frame = -(10**9)  # the last attempt before T_rel exists
        self.seconds = 0.0  # spent estimating T_rel (`_estimate`), for the stage timings

    def after_target_frame(self, frame_index: int, associations: list[Association]) -> list[RegistrationEvent]:
        """Note what a target frame's association changed; estimate T_rel if it is time to."""
        started = time.perf_counter()
        try:
            return self._after_target_frame(frame_index, associations)
        finally:
            self.seconds += time.perf_counter() - started

    def _after_target_frame(self, frame_index: int, associations: list[Association]) -> list[RegistrationEvent]:
        self.centers.stale(a.object_id for a in associations if a.created or a.replaced)
        created = any(a.created for a in associations)
        if self.registration is None:
            if not created and frame_index - self._last_try_frame < self.ransac.retry_frames:
                return []
            self._last_try_frame = frame_index
            return self._estimate(frame_index)
        if created and len(self.registration.inliers) < self.ransac.enough_inliers:
            return self._estimate(frame_index)
        return []

    def registered_centers(self) -> np.ndarray:
        """(n, 3) the target objects' centers in the source world (row i: object i); needs T_rel."""
        assert self.registration is not None
        return self.centers.get(self.registration.transform, self.target)

    def target_objects_in(self, region: Region, margin: float = 0.0) -> list[int]:
        """Target objects whose registered centers fall in `region` (of the source's tree) grown by
        `margin`; needs T_rel."""
        return np.flatnonzero(region.contains(self.registered_centers(), margin)).tolist()

    def shape_pairs(self) -> list[tuple[int, int]]:
        """(target, source) candidate pairs: each target object's most similar source objects above delta_s."""
        source, target = self.source, self.target
        if not source.objects:
            return []
        source_ids = np.array(sorted(source.objects))
        source_codes = np.array([source.objects[i].shape_code for i in source_ids])
        pairs = []
        for target_id in sorted(target.objects):
            similarity = cosine_similarity(target.objects[target_id].shape_code, source_codes)
            order = np.argsort(-similarity, kind="stable")[: self.ransac.candidates]
            pairs += [(target_id, int(source_ids[j])) for j in order if similarity[j] > self.shape_similarity]
        return pairs

    def add_prior(self, prior: RegistrationPrior) -> None:
        """A T_rel hypothesis from outside the object maps, verified by the pairs at every attempt
        (ignored with the priors off: `PriorConfig.enabled`)."""
        if self.prior_config.enabled:
            self.priors.append(prior)

    def _estimate(self, frame_index: int) -> list[RegistrationEvent]:
        source, target = self.source, self.target
        pairs = self.shape_pairs()
        target_centers = {i: o.center_world for i, o in target.objects.items()}
        source_centers = {i: o.center_world for i, o in source.objects.items()}
        candidates: list[tuple[Registration | None, bool]] = []  # (estimate, passes its bar)
        verified = []  # the priors and how the pairs verify them
        # A scene alignment whose own evidence is weak is one more hypothesis: as many pairs confirm it
        # as would accept RANSAC's fit (as many as the source has, in a small map), not two chance ones
        # (a shelf's units turned half a turn: docs/registration.md, "A weak prior"). Given poses
        # that share a world are no search's outcome: their two pairs, as before.
        weak_min = max(self.prior_config.min_inliers, min(self.ransac.min_inliers, len(source.objects)))
        for prior in self.priors:
            check = verify_prior(prior, pairs, target_centers, source_centers, self.config.inlier_m,
                                 support_m=self.prior_config.support_m)
            searched = prior.method == "scene alignment" and not prior.standalone
            confirmed = len(check.inliers) >= (weak_min if searched else self.prior_config.min_inliers)
            if not confirmed and prior.standalone:  # too few pairs: it stands on the scene's own evidence
                check = dataclasses.replace(check, method=OWN_EVIDENCE[prior.method], evidence=prior.evidence)
            verified.append((prior, check, confirmed or prior.standalone))
        # A binding prior vetoes RANSAC's fits only while the objects support it: one they do not
        # (a confident but wrong scene alignment) must not stop a registration they do support. Nor
        # does any prior veto a fit of `enough_inliers` pairs or more: the veto is against layouts of
        # a few objects that fit by chance, and that many do not (a wrong scene alignment that two
        # pairs happened to confirm vetoed the hand-held office's 12-pair registration: docs/registration.md).
        vetoes = [prior for prior, _, supported in verified if prior.binding and supported]
        enough = self.ransac.enough_inliers
        # A small source map may have fewer objects than N: then all of them are enough (`small_maps`).
        needed = min(self.config.pairs, len(source.objects)) if self.ransac.small_maps else self.config.pairs
        if len({t for t, _ in pairs}) >= needed:
            result = ransac_registration(pairs, target_centers, source_centers, self.config.inlier_m,
                                         seed=self.config.seed)
            many = result is not None and 0 < enough <= len(result.inliers)
            candidates.append((result, result is not None and len(result.inliers) >= self.ransac.min_inliers
                               and (many or _agrees_with(result, vetoes, pairs, target_centers, self.config.inlier_m))))
        candidates += [(check, supported) for _, check, supported in verified]
        passing = [r for r, ok in candidates if ok and r is not None]
        best = max(passing, key=lambda r: len(r.inliers), default=None)  # the first (RANSAC's) on a tie
        if best is not None and (self.registration is None or len(best.inliers) > len(self.registration.inliers)):
            self.registration = best
        return [self._event(frame_index, pairs, r, accepted=r is not None and r is self.registration and r is best)
                for r, _ in candidates]

    def _event(self, frame_index: int, pairs: list[tuple[int, int]], result: Registration | None,
               accepted: bool) -> RegistrationEvent:
        source, target = self.source, self.target
        if result is None:
            return RegistrationEvent(frame_index=frame_index, accepted=False, n_pairs=len(pairs), n_hypotheses=0,
                                     transform=None, inlier_pairs=(), residual_m=float("nan"),
                                     target_centers=np.zeros((0, 3)), source_centers=np.zeros((0, 3)))
        inlier_pairs = tuple(pairs[i] for i in result.inliers)
        return RegistrationEvent(
            frame_index=frame_index, accepted=accepted, n_pairs=len(pairs), n_hypotheses=result.n_hypotheses,
            transform=result.transform, inlier_pairs=inlier_pairs, residual_m=result.residual_m, method=result.method,
            evidence=result.evidence,
            target_centers=np.array([target.objects[t].center_world for t, _ in inlier_pairs]).reshape(-1, 3),
            source_centers=np.array([source.objects[s].center_world for _, s in inlier_pairs]).reshape(-1, 3))


def _agrees_with(result: Registration, priors: list[RegistrationPrior], pairs: list[tuple[int, int]],
                 target_centers: dict[int, np.ndarray], inlier_m: float) -> bool:
    """With no prior, any estimate; else one that puts its inliers' target centers within 2 inlier_m
    of where some prior puts them (few objects make layouts that fit by chance; the scene does not)."""
    if not priors:
        return True
    centers = np.array([target_centers[pairs[i][0]] for i in result.inliers]).reshape(-1, 3)
    return any(np.max(np.linalg.norm(apply(result.transform, centers) - apply(p.transform, centers), axis=1))
               <= 2 * inlier_m for p in priors)
