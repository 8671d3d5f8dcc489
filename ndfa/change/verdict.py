"""The change test of one target object O (paper Sec. IV-B), as a pure function of its evidence.

O's center is registered into the source world with T_rel; the source objects of the tree cell it
lands in are its source neighbourhood. O is changed when none of them looks like it (shape cosine
similarity above delta_s); otherwise its local graph is compared with each shape match's, most
similar first, and O is unchanged with the first consistent one (`ndfa.change.graph`).

Online, O's neighbours come into view one by one, so a verdict may rest on half the evidence:
the test then says "undecided" and what it would say if no more evidence came (`otherwise`).
Nothing here changes state; `ndfa.change.policy` decides when a verdict is acted on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ndfa.change.associate import SessionObject
from ndfa.change.config import DecisionConfig
from ndfa.change.graph import GraphComparison, LocalGraph, compare_graphs, local_graph

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
    which; `otherwise` is the verdict if none does)."""

    kind: VerdictKind
    reason: str
    partner_id: int | None = None
    comparisons: tuple[Comparison, ...] = ()  # the graph comparisons made, in order
    otherwise: Verdict | None = None


def shape_verdict(source_ids: list[int], similarity: dict[int, float], shape_similarity: float) -> Verdict | None:
    """"changed" when no source object around O's registered center looks like O; None when one
    does (the graphs decide: `graph_verdict`)."""
    if not source_ids:
        return Verdict("changed", "no source objects around it")
    if not any(similarity[s] > shape_similarity for s in source_ids):
        return Verdict("changed", f"no shape match among {len(source_ids)} source objects around it")
    return None


def graph_verdict(
    target_graph: LocalGraph,
    center_source: np.ndarray,
    source_ids: list[int],
    similarity: dict[int, float],
    source_objects: dict[int, SessionObject],
    rotation: np.ndarray,
    shape_similarity: float,
    decision: DecisionConfig,
    target_scatter_m: float = 0.0,
) -> Verdict:
    """O's local graph (`target_graph`, over its target neighbours) against the graph of each shape
    match among `source_ids` (its source neighbourhood; `similarity`: to O, by source id).

    center_source: T_rel t_O; rotation: T_rel's rotation (target-world vectors -> source world).
    target_scatter_m: O's center scatter, which with its match's widens the position tests
    (`DecisionConfig.scatter_factor`).
    Undecided when O has no target neighbour while the source neighbourhood has company (the lone
    test would judge it on T_rel's absolute accuracy alone), and when no graph agrees while O has
    fewer target neighbours than its match has source neighbours (the one that stayed may not
    have been seen yet).
    """
    matches = [s for s in source_ids if similarity[s] > shape_similarity]
    comparisons: list[Comparison] = []
    partner_id = None
    for source_id in sorted(matches, key=lambda s: -similarity[s]):
        source_graph = local_graph(source_id, source_ids, source_objects)
        partner = source_objects[source_id]
        distance = float(np.linalg.norm(center_source - partner.center_world))
        slack = decision.scatter_factor * float(np.hypot(target_scatter_m, partner.center_scatter_m))
        in_place_m = decision.in_place_m + slack if decision.in_place_m > 0 else 0.0
        result = compare_graphs(target_graph, source_graph, similarity[source_id], distance, rotation,
                                shape_similarity, decision.edge_m, decision.fallback_distance_m + slack, in_place_m)
        comparisons.append(Comparison(result, target_graph, source_graph))
        if result.consistent:
            partner_id = source_id
            break
    if partner_id is None:
        verdict = Verdict("changed", f"no consistent local graph with {len(matches)} shape matches",
                          comparisons=tuple(comparisons))
    else:
        verdict = Verdict("unchanged", f"consistent with source object {partner_id}", partner_id, tuple(comparisons))
    target_neighbours, source_neighbours = len(target_graph.neighbour_ids), len(source_ids) - 1
    if target_neighbours == 0 and source_neighbours > 0:
        return Verdict("undecided", "alone in its target neighbourhood, not in the source's", otherwise=verdict)
    if verdict.kind == "changed" and target_neighbours < source_neighbours:
        return Verdict("undecided", f"{target_neighbours} target neighbours, {source_neighbours} in the source",
                       comparisons=verdict.comparisons, otherwise=verdict)
    return verdict
