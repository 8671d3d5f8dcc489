"""Whether a scene alignment (or the shared world of given poses) holds on its own evidence, when
the object pairs cannot confirm it.

The paper registers two sessions by shape-matched objects that stayed; a scene alignment
(`ndfa.run.align`) is normally accepted only when two such pairs agree with it. On a
table where most objects changed there are not two, and that is the case a change detector exists
for. The static scene itself (floor, walls, furniture) then registers the sessions, but only when
its evidence is strong, each figure measured on the clouds:

- **overlap**: a share of the target's *upright* points (walls, furniture, object sides; normals
  off the vertical) lies within `icp_distance_m` of the source's, with a small RMS distance.
  Floors and table tops coincide under any shift once both worlds are levelled, so they count for
  nothing here.
- **agreement of independent subsets**: the target cloud is cut into halves along x and along y
  (four halves, two disjoint pairs); each half is aligned onto the source from scratch (its own
  FPFH + RANSAC, its own ICP; nothing of the whole's result). A half *agrees* when it lands where
  the whole did (within `agree_m` at the half's center and `agree_deg` about up); it *contradicts*
  when it lands elsewhere, beyond the ICP's reach of the whole's alignment (its points moved by
  more than `bend_m`, RMS), and fits better there than at the whole's alignment (by more than
  `contradict_margin` of its points). A half that lands within reach but outside the agreement's
  bars is *bent*: a cloud the odometry bent a few centimetres or degrees, whose halves each fit a
  little apart. Otherwise a half says nothing (one that fits itself turned half a turn as well, or
  whose own search found a poorer fit). No half may contradict, and at least `min_agreeing` must
  agree, or all four must land within reach (agree or be bent): one registration of a bent cloud,
  whose precision the rmse bar above judges. Poses that bent a session's cloud far (odometry that
  failed), or a scene that aligns several ways (rooms of identical tables, a corridor), make the
  halves land in different places.
- **no rival**: the whole alignment turned by 90, 180 and 270 degrees about the target's center,
  or shifted by 0.6 or 1.2 m along x or y, and refined by ICP, must overlap clearly less
  (`rival_ratio`): a rectangular room fits itself turned half a turn, a row of identical tables
  shifted by one.

Any figure short of its bar rejects the alignment, and the reason names it; `ndfa detect` then
says "no registration" with the figures. Why these bars: `docs/registration.md`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.geometry import make_pose, rotation_z
from ndfa.run.cloud_align import (
    AlignConfig,
    SceneEvidenceConfig,
    apply_transform,
    global_alignment,
    icp_coarse_to_fine,
    icp_yaw,
    overlap,
    upright,
)

# Rival shifts: rows of identical tables or desks repeat at about a table's pitch.
RIVAL_SHIFTS_M = (0.6, 1.2)


@dataclass(frozen=True)
class SubsetCheck:
    """One half of the target cloud, aligned on its own, against the whole's alignment."""

    half: str            # "x<", "x>", "y<", "y>": which side of the target's median
    points: int
    fitness: float       # the half's own alignment: share of its points near the source's
    shift_m: float       # horizontal distance, at the half's center, between its alignment and the whole's
    turn_deg: float      # turn about up between them
    fitness_at_whole: float  # the half's fitness at the whole's alignment (refined by ICP from it)
    moved_m: float = float("inf")  # RMS horizontal distance between the half's points under its alignment and the whole's
    transform: np.ndarray | None = field(default=None, compare=False, repr=False)  # the half's own alignment

    def as_dict(self) -> dict:
        return {"half": self.half, "points": self.points, "fitness": round(self.fitness, 3),
                "shift_m": round(self.shift_m, 4), "turn_deg": round(self.turn_deg, 2),
                "fitness_at_whole": round(self.fitness_at_whole, 3),
                "moved_m": round(self.moved_m, 4) if np.isfinite(self.moved_m) else None}


@dataclass(frozen=True)
class OwnEvidence:
    """The figures of a scene alignment's own evidence, and the verdict on them."""

    ok: bool
    reason: str                   # one line: why it holds or the first figure short of its bar
    upright_fitness: float
    upright_rmse_m: float
    subsets: tuple[SubsetCheck, ...] = ()
    rival_fitness: float = float("nan")  # the best upright overlap of the alignment turned or shifted
    config: SceneEvidenceConfig = field(default_factory=SceneEvidenceConfig)

    @property
    def upright_overlap(self) -> bool:
        """Whether the upright surfaces overlap by the first bar (`min_fitness`), whatever the rest."""
        return bool(np.isfinite(self.upright_fitness) and self.upright_fitness >= self.config.min_fitness)

    def describe(self) -> str:
        """One line with every figure measured."""
        parts = [f"upright fitness {self.upright_fitness:.2f}"]
        if np.isfinite(self.upright_rmse_m):
            parts.append(f"rmse {self.upright_rmse_m * 100:.1f} cm")
        if self.subsets:
            verdicts = [self.verdict(s) for s in self.subsets]
            agreeing = [s for s, v in zip(self.subsets, verdicts) if v == "agrees"]
            worst = "" if not agreeing else \
                f" within {max(s.shift_m for s in agreeing) * 100:.1f} cm, {max(s.turn_deg for s in agreeing):.1f} deg"
            bent = [s for s, v in zip(self.subsets, verdicts) if v == "bent"]
            within = "" if not bent else \
                f", {len(bent)} bent (within {max(s.moved_m for s in bent) * 100:.1f} cm RMS)"
            parts.append(f"{len(agreeing)}/{len(self.subsets)} independent halves agree{worst}{within}, "
                         f"{verdicts.count('contradicts')} contradict")
        if np.isfinite(self.rival_fitness):
            parts.append(f"best rival {self.rival_fitness:.2f}")
        return f"{'holds' if self.ok else 'weak'}: {self.reason}; " + ", ".join(parts)

    def as_dict(self) -> dict:
        def number(value: float) -> float | None:
            return None if not np.isfinite(value) else round(float(value), 4)

        return {"ok": self.ok, "reason": self.reason, "upright_fitness": number(self.upright_fitness),
                "upright_rmse_m": number(self.upright_rmse_m), "subsets": [s.as_dict() for s in self.subsets],
                "rival_fitness": number(self.rival_fitness)}

    def verdict(self, subset: SubsetCheck) -> str:
        """"agrees", "bent", "contradicts" or "silent" (see the module docstring)."""
        if subset.points < self.config.min_half_points:
            return "silent"
        if subset.shift_m <= self.config.agree_m and subset.turn_deg <= self.config.agree_deg:
            return "agrees"
        if subset.moved_m <= self.config.bend_m:
            return "bent"
        if subset.fitness > subset.fitness_at_whole + self.config.contradict_margin:
            return "contradicts"
        return "silent"

    def halves_hold(self) -> bool:
        """`min_agreeing` halves agree, or all four land within reach (agree or are bent)."""
        verdicts = [self.verdict(s) for s in self.subsets]
        return verdicts.count("agrees") >= self.config.min_agreeing or \
            (len(verdicts) == 4 and all(v in ("agrees", "bent") for v in verdicts))


def own_evidence(source_cloud: np.ndarray, target_cloud: np.ndarray, transform: np.ndarray,
                 align: AlignConfig = AlignConfig()) -> OwnEvidence:
    """Judge `transform` (target world -> source world, both levelled) on the clouds alone, by the
    bars of `align.evidence` (the defaults when it is None)."""
    config = align.evidence or SceneEvidenceConfig()
    source_upright, target_upright = upright(source_cloud, align), upright(target_cloud, align)
    if min(len(source_upright), len(target_upright)) < config.min_half_points:
        return OwnEvidence(False, "too few upright points to judge", float("nan"), float("nan"), config=config)
    fitness, rmse = overlap(source_upright, target_upright, transform, align.icp_distance_m)
    if fitness < config.min_fitness:
        return OwnEvidence(False, f"the upright surfaces overlap too little (below {config.min_fitness})",
                           fitness, rmse, config=config)
    if not rmse <= config.max_rmse_m:
        return OwnEvidence(False, f"the overlap's rmse is above {config.max_rmse_m * 100:g} cm", fitness, rmse,
                           config=config)
    subsets = tuple(_subset_checks(source_cloud, target_cloud, transform, align))
    evidence = OwnEvidence(False, "", fitness, rmse, subsets, config=config)
    contradicting = [s for s in subsets if evidence.verdict(s) == "contradicts"]
    if contradicting:
        s = contradicting[0]
        return dataclasses.replace(evidence, reason=(
            f"the half {s.half} fits better {s.shift_m * 100:.0f} cm / {s.turn_deg:.0f} deg from the whole's "
            f"alignment ({s.fitness:.2f} against {s.fitness_at_whole:.2f})"))
    if not evidence.halves_hold():
        agreeing = sum(evidence.verdict(s) == "agrees" for s in subsets)
        return dataclasses.replace(evidence, reason=f"{agreeing} independent halves agree with it, fewer than "
                                                    f"{config.min_agreeing}, and not all land within reach")
    rival = _rival_fitness(source_cloud, target_cloud, source_upright, target_upright, transform, align)
    evidence = dataclasses.replace(evidence, rival_fitness=rival)
    if rival >= config.rival_ratio * fitness:
        return dataclasses.replace(evidence, reason=f"ambiguous: turned or shifted, the scene overlaps {rival:.2f} "
                                                    f"(at least {config.rival_ratio:g} of {fitness:.2f})")
    return dataclasses.replace(evidence, ok=True, reason="the static scene registers the sessions on its own")


def better_from_halves(source_cloud: np.ndarray, target_cloud: np.ndarray, evidence: OwnEvidence,
                       fitness: float, align: AlignConfig = AlignConfig()) -> tuple[np.ndarray, float, float] | None:
    """(transform, fitness, rmse) of the whole target cloud at a contradicting half's own alignment,
    refined by ICP, where the whole fits there better than `fitness` (its alignment's) by the
    contradiction's margin; else None. RANSAC stops at its first fit above the bar, and a room
    can fit itself half a turn off well enough (a furnished room: 0.76 there, 0.96 at the half's)."""
    best = None
    for subset in evidence.subsets:
        if evidence.verdict(subset) != "contradicts" or subset.transform is None:
            continue
        transform = icp_coarse_to_fine(source_cloud, target_cloud, subset.transform, align)
        found, rmse = overlap(source_cloud, target_cloud, transform, align.icp_distance_m)
        if found > fitness + evidence.config.contradict_margin and (best is None or found > best[1]):
            best = (transform, found, rmse)
    return best


def _subset_checks(source_cloud: np.ndarray, target_cloud: np.ndarray, transform: np.ndarray,
                   align: AlignConfig) -> list[SubsetCheck]:
    """Each half of the target cloud (either side of its median x, then y) aligned from scratch."""
    checks = []
    for axis, name in ((0, "x"), (1, "y")):
        median = float(np.median(target_cloud[:, axis]))
        for side, half in (("<", target_cloud[:, axis] < median), (">", target_cloud[:, axis] >= median)):
            points = target_cloud[half]
            if len(points) < 3:
                checks.append(SubsetCheck(name + side, len(points), 0.0, float("inf"), float("inf"), 0.0))
                continue
            own_transform, own_fitness, _ = global_alignment(source_cloud, points, align)
            at_whole, _ = overlap(source_cloud, points, icp_yaw(source_cloud, points, transform, align),
                                  align.icp_distance_m)
            center = points.mean(axis=0)
            shift = apply_transform(own_transform, center[None])[0] - apply_transform(transform, center[None])[0]
            difference = own_transform[:3, :3] @ transform[:3, :3].T
            turn = abs(float(np.degrees(np.arctan2(difference[1, 0], difference[0, 0]))))
            moved = apply_transform(own_transform, points)[:, :2] - apply_transform(transform, points)[:, :2]
            checks.append(SubsetCheck(name + side, len(points), own_fitness, float(np.linalg.norm(shift[:2])), turn,
                                      at_whole, float(np.sqrt(np.mean(np.sum(moved**2, axis=1)))), own_transform))
    return checks


def _rival_fitness(source_cloud: np.ndarray, target_cloud: np.ndarray, source_upright: np.ndarray,
                   target_upright: np.ndarray, transform: np.ndarray, align: AlignConfig) -> float:
    """The best upright overlap of the alignment moved to a rival: turned by a quarter, a half and
    three quarters about the target's center, or shifted by `RIVAL_SHIFTS_M` along x or y; each
    refined by the same ICP (coarse to fine). A start that ICP brings back is no rival."""
    pivot = np.array([*apply_transform(transform, target_cloud)[:, :2].mean(axis=0), 0.0])
    probe = target_cloud[:: max(1, len(target_cloud) // 200)]
    starts = [make_pose(rotation_z(quarter * np.pi / 2), pivot - rotation_z(quarter * np.pi / 2) @ pivot)
              for quarter in (1, 2, 3)]
    starts += [make_pose(np.eye(3), np.array(step)) for d in RIVAL_SHIFTS_M
               for step in ((d, 0, 0), (-d, 0, 0), (0, d, 0), (0, -d, 0))]
    best = 0.0
    for start in starts:
        rival = icp_coarse_to_fine(source_cloud, target_cloud, start @ transform, align)
        back = np.linalg.norm(apply_transform(rival, probe) - apply_transform(transform, probe), axis=1).max()
        if back <= 2 * align.icp_distance_m:
            continue
        best = max(best, overlap(source_upright, target_upright, rival, align.icp_distance_m)[0])
    return best
