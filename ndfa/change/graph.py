"""Local object graphs and their comparison (paper Sec. IV-B, Fig. 5).

The graph of object o in its neighbourhood has an edge e_oi = t_i - t_o to every other object i
of the neighbourhood. To compare the graph of a target object O with that of a source object o'
(a shape match of O), each target neighbour j is paired with a source neighbour j' that matches
it by shape (similarity above the threshold), and the edge pair counts as consistent when
|R e_Oj - e_o'j'| <= delta_e, R being the rotation of T_rel (edges are differences, so the
translation drops out). O is unchanged with respect to o' when at least one edge pair is
consistent: some neighbour kept its place relative to it.

Among several shape matches j' of j, the one with the smallest edge error is taken (the paper
takes "the" vertex match). Mugs of one table often look alike to the codes; insisting on the
single most similar one would pair a neighbour with the wrong mug and call an unchanged object
changed. The shape test still decides which neighbours may pair, and a switch of two mugs still
leaves no consistent edge, because both edges then point the other way.

When O or o' is alone in its neighbourhood there are no edges, and the comparison falls back to
the objects themselves: unchanged when the registered centers are within `fallback_distance_m`.

ndfa adds one test to the paper's: O is also unchanged when no edge agrees but O itself stands
within `in_place_m` of o' after registration ("in place"): on a table where every other object
changed, the one that stayed has no neighbour to agree with (`docs/detector.md`). It can only turn
"changed" into "unchanged", and only for an object whose shape match is where T_rel puts it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.change.associate import SessionObject, cosine_similarity
from ndfa.core.events import GraphMode


@dataclass(frozen=True)
class LocalGraph:
    """Object `center_id`'s graph: its neighbours, their shape codes and the edges to them."""

    center_id: int
    neighbour_ids: np.ndarray  # (M,) other objects of the neighbourhood
    codes: np.ndarray          # (M, D) their shape codes
    edges: np.ndarray          # (M, 3) t_neighbour - t_center, in the graph's world frame


@dataclass(frozen=True)
class EdgePair:
    target_neighbour: int
    source_neighbour: int
    similarity: float
    edge_error_m: float     # |R e_Oj - e_o'j'|
    consistent: bool


@dataclass(frozen=True)
class GraphComparison:
    """The outcome of comparing target object O's graph with one shape-matched source object's."""

    target_id: int
    source_id: int
    similarity: float            # shape similarity of O and o'
    mode: GraphMode              # "graph", "in place" (no edge agreed, O is at o's place) or
                                 # "fallback" (a lone object: compared directly)
    edge_pairs: tuple[EdgePair, ...]
    distance_m: float            # |T_rel t_O - t_o'|, reported in both modes
    consistent: bool             # O unchanged with respect to o'


def local_graph(center_id: int, neighbour_ids: list[int], objects: dict[int, SessionObject]) -> LocalGraph:
    """The graph of `objects[center_id]` over the objects `neighbour_ids` (itself left out)."""
    others = [i for i in neighbour_ids if i != center_id]
    center = objects[center_id]
    return LocalGraph(
        center_id,
        np.array(others, dtype=int),
        np.array([objects[i].shape_code for i in others]).reshape(len(others), len(center.shape_code)),
        np.array([objects[i].center_world - center.center_world for i in others]).reshape(len(others), 3),
    )


def compare_graphs(
    target: LocalGraph,
    source: LocalGraph,
    similarity: float,
    distance_m: float,
    rotation: np.ndarray,
    shape_similarity: float,
    edge_m: float,
    fallback_distance_m: float,
    in_place_m: float = 0.0,
) -> GraphComparison:
    """Whether target object O (graph `target`) is unchanged with respect to source object o'.

    `rotation` turns target-world vectors into the source world (T_rel's rotation); `distance_m`
    is the registered center distance, used by the fallback for lone objects.
    """
    if len(target.neighbour_ids) == 0 or len(source.neighbour_ids) == 0:
        return GraphComparison(target.center_id, source.center_id, similarity, "fallback", (),
                               distance_m, distance_m <= fallback_distance_m)
    pairs = []
    for j, code, edge in zip(target.neighbour_ids, target.codes, target.edges):
        similarities = cosine_similarity(code, source.codes)
        matches = np.flatnonzero(similarities > shape_similarity)
        if len(matches) == 0:
            continue  # no source neighbour looks like j: no edge to compare
        errors = np.linalg.norm(rotation @ edge - source.edges[matches], axis=1)
        best = matches[int(np.argmin(errors))]
        error = float(errors.min())
        pairs.append(EdgePair(int(j), int(source.neighbour_ids[best]), float(similarities[best]), error, error <= edge_m))
    if any(p.consistent for p in pairs) or distance_m > in_place_m:
        return GraphComparison(target.center_id, source.center_id, similarity, "graph", tuple(pairs), distance_m,
                               any(p.consistent for p in pairs))
    return GraphComparison(target.center_id, source.center_id, similarity, "in place", tuple(pairs), distance_m, True)
