"""The change test of one target object O (paper Sec. IV-B), as a pure function of its evidence.

O's center is registered into the source world with T_rel; the source objects of the tree cell it
lands in are its source neighbourhood. O is changed when none of them looks like it (shape cosine
similarity above delta_s); otherwise its local graph is compared with each shape match's, most
similar first, and O is unchanged with the first consistent one (`ndfa.change.graph`).

Online, O's neighbours come into view one by one, so a verdict may rest on half the evidence:
the test then says "undecided" and what it would say if no more evidence came (`otherwise`).
Nothing here changes state; `ndfa.change.policy` decides when a verdict is acted on.

Each verdict also says how far O's best agreement with a source object falls short of the test's
bar (`Verdict.shortfall`, a ratio: at most 1 O agrees, above 1 it does not), which
`decision_score` turns into the decision's score in [0, 1] (docs/scores.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ndfa.change.associate import SessionObject
from ndfa.change.config import DetectorConfig
from ndfa.change.graph import GraphComparison, LocalGraph, compare_graphs, local_graph
from ndfa.core.events import CHANGE_SCORE

VerdictKind = Literal["unchanged", "changed", "undecided"]


@dataclass(frozen=True)
class Comparison:
    """One comparison of O's graph with a shape match's, with both graphs (the sinks draw them)."""

    result: GraphComparison
    target_graph: LocalGraph
    source_graph: LocalGraph


@dataclass(frozen=True)
class Verdict:
    """What the test says about O: "unchanged" (with `partner_id`, the consistent source object),
    "changed" (with the reason), or "undecided" (more evidence may still come: the reason says
    which; `otherwise` is the verdict if none does).

    shortfall: how far O's best agreement with a source object falls short of the bar, as a ratio
    (<= 1 for "unchanged", > 1 for "changed", inf with nothing around it; NaN: not computed). For a
    shape verdict, (1 - s*) / (1 - delta_s) with s* the best shape similarity around O; for a graph
    verdict, the smallest over the compared shape matches o' of max(shape part, position part):
    the shape part (1 - sim(O, o')) / (1 - delta_s), the position part the best edge error over
    delta_e or the distance over the in-place distance ("graph"), or the distance over the
    lone-object distance ("fallback"), each test's own allowance (`shortfall_of`)."""

    kind: VerdictKind
    reason: str
    partner_id: int | None = None
    comparisons: tuple[Comparison, ...] = ()  # the graph comparisons made, in order
    otherwise: Verdict | None = None
    shortfall: float = float("nan")


def shape_shortfall(similarity: float, shape_similarity: float) -> float:
    """(1 - similarity) / (1 - delta_s): 1 at the shape test's bar, above 1 below it (unlike)."""
    return (1.0 - similarity) / max(1.0 - shape_similarity, 1e-9)


def shortfall_of(result: GraphComparison, shape_similarity: float, edge_m: float, fallback_m: float,
                 in_place_m: float) -> float:
    """How far one comparison of O with o' falls short of "unchanged" (<= 1 when it is consistent,
    > 1 when not): the worse of its shape part and its position part (`Verdict.shortfall`); the
    distances are the ones `compare_graphs` was given (with the scatter slack)."""
    if result.mode == "fallback":
        position = _ratio(result.distance_m, fallback_m)
    else:
        errors = [p.edge_error_m for p in result.edge_pairs]
        position = _ratio(min(errors), edge_m) if errors else np.inf
        if in_place_m > 0:  # the in-place test: unchanged this close, whatever the edges say
            position = min(position, _ratio(result.distance_m, in_place_m))
    ratio = max(shape_shortfall(result.similarity, shape_similarity), position)
    # The ratio is the decision's own arithmetic, rounded: keep it on the side the test took.
    return min(ratio, 1.0) if result.consistent else max(ratio, float(np.nextafter(1.0, 2.0)))


def decision_score(verdict: Verdict) -> float:
    """The score of a decision taken on `verdict` ("unchanged" or "changed"): shortfall / (1 +
    shortfall), in [0, 1], 1 with nothing around O. A change scores at least `CHANGE_SCORE` (0.5)
    and "unchanged" below it, so thresholding at 0.5 gives the detector's own decisions."""
    ratio = verdict.shortfall
    score = 1.0 if np.isinf(ratio) else ratio / (1.0 + ratio) if np.isfinite(ratio) else CHANGE_SCORE
    if verdict.kind == "changed":
        return max(score, CHANGE_SCORE)
    return min(score, float(np.nextafter(CHANGE_SCORE, 0.0)))


def removal_score(observers: int) -> float:
    """The score of a removal: how much of the source object the target should have seen, counted
    as the distinct tested target objects around it (none of which matched it), n / (1 + n):
    0.5 for one, 0.75 for three. At least `CHANGE_SCORE`: every removal is a reported change."""
    return max(observers / (1.0 + observers), CHANGE_SCORE)


def _ratio(value: float, allowance: float) -> float:
    if allowance <= 0:
        return 0.0 if value <= 0 else np.inf
    return value / allowance


def shape_verdict(source_ids: list[int], similarity: dict[int, float], shape_similarity: float) -> Verdict | None:
    """"changed" when no source object around O's registered center looks like O; None when one
    does (the graphs decide: `graph_verdict`)."""
    if not source_ids:
        return Verdict("changed", "no source objects around it", shortfall=np.inf)
    if not any(similarity[s] > shape_similarity for s in source_ids):
        best = max(similarity[s] for s in source_ids)
        return Verdict("changed", f"no shape match among {len(source_ids)} source objects around it",
                       shortfall=shape_shortfall(best, shape_similarity))
    return None


def graph_verdict(
    target_graph: LocalGraph,
    center_source: np.ndarray,
    source_ids: list[int],
    similarity: dict[int, float],
    source_objects: dict[int, SessionObject],
    rotation: np.ndarray,
    shape_similarity: float,
    config: DetectorConfig,
    target_scatter_m: float = 0.0,
) -> Verdict:
    """O's local graph (`target_graph`, over its target neighbours) against the graph of each shape
    match among `source_ids` (its source neighbourhood; `similarity`: to O, by source id).

    center_source: T_rel t_O; rotation: T_rel's rotation (target-world vectors -> source world).
    target_scatter_m: O's center scatter, which with its match's widens the position tests
    (`DriftConfig.scatter_factor`).
    Undecided when O has no target neighbour while the source neighbourhood has company (the lone
    test would judge it on T_rel's absolute accuracy alone), and when no graph agrees while O has
    fewer target neighbours than its match has source neighbours (the one that stayed may not
    have been seen yet); with `WaitingConfig.neighbours` off, neither waits.
    """
    decision, in_place = config.decision, config.evidence.in_place_m
    matches = [s for s in source_ids if similarity[s] > shape_similarity]
    comparisons: list[Comparison] = []
    shortfalls: list[float] = []
    partner_id = None
    for source_id in sorted(matches, key=lambda s: -similarity[s]):
        source_graph = local_graph(source_id, source_ids, source_objects)
        partner = source_objects[source_id]
        distance = float(np.linalg.norm(center_source - partner.center_world))
        slack = config.drift.scatter_factor * float(np.hypot(target_scatter_m, partner.center_scatter_m))
        in_place_m = in_place + slack if in_place > 0 else 0.0
        result = compare_graphs(target_graph, source_graph, similarity[source_id], distance, rotation,
                                shape_similarity, decision.edge_m, decision.fallback_distance_m + slack, in_place_m)
        comparisons.append(Comparison(result, target_graph, source_graph))
        shortfalls.append(shortfall_of(result, shape_similarity, decision.edge_m, decision.fallback_distance_m + slack,
                                       in_place_m))
        if result.consistent:
            partner_id = source_id
            break
    shortfall = min(shortfalls, default=np.inf)
    if partner_id is None:
        verdict = Verdict("changed", f"no consistent local graph with {len(matches)} shape matches",
                          comparisons=tuple(comparisons), shortfall=shortfall)
    else:
        verdict = Verdict("unchanged", f"consistent with source object {partner_id}", partner_id, tuple(comparisons),
                          shortfall=shortfall)
    target_neighbours, source_neighbours = len(target_graph.neighbour_ids), len(source_ids) - 1
    if not config.waiting.neighbours:
        return verdict
    if target_neighbours == 0 and source_neighbours > 0:
        return Verdict("undecided", "alone in its target neighbourhood, not in the source's", otherwise=verdict,
                       shortfall=shortfall)
    if verdict.kind == "changed" and target_neighbours < source_neighbours:
        return Verdict("undecided", f"{target_neighbours} target neighbours, {source_neighbours} in the source",
                       comparisons=verdict.comparisons, otherwise=verdict, shortfall=shortfall)
    return verdict
