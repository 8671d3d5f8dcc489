"""Events that show the detector's state to the sinks: a session's object tree, one graph comparison."""

from __future__ import annotations

import numpy as np

from ndfa.change.associate import SessionMap
from ndfa.change.verdict import Comparison
from ndfa.core.events import GraphEvent, Session, TreeEvent


def tree_event(session: Session, frame_index: int, session_map: SessionMap) -> TreeEvent:
    tree = session_map.tree
    x_nodes, y_nodes = tree.x.nodes, tree.y.nodes
    cells = []
    for i, nx in enumerate(x_nodes):
        for j, ny in enumerate(y_nodes):
            shared = nx.objects & ny.objects
            if shared:
                cells.append((i, j, tuple(sorted(shared))))
    z_nodes = [] if tree.z is None else tree.z.nodes
    return TreeEvent(session=session, frame_index=frame_index,
                     x_intervals=np.array([[n.low, n.high] for n in x_nodes]).reshape(-1, 2),
                     y_intervals=np.array([[n.low, n.high] for n in y_nodes]).reshape(-1, 2), cells=cells,
                     z_intervals=np.array([[n.low, n.high] for n in z_nodes]).reshape(-1, 2),
                     z_objects=[tuple(sorted(n.objects)) for n in z_nodes])


def graph_event(frame_index: int, comparison: Comparison, center_source: np.ndarray, partner_center: np.ndarray,
                rotation: np.ndarray) -> GraphEvent:
    """comparison: of target object O (registered to `center_source`) with the source object at
    `partner_center`; rotation: T_rel's, which turns O's edges into the source world."""
    result, target_graph, source_graph = comparison.result, comparison.target_graph, comparison.source_graph
    by_target = {int(j): k for k, j in enumerate(target_graph.neighbour_ids)}
    by_source = {int(j): k for k, j in enumerate(source_graph.neighbour_ids)}
    pairs = result.edge_pairs
    return GraphEvent(
        frame_index=frame_index, target_id=result.target_id, source_id=result.source_id,
        similarity=result.similarity, mode=result.mode, consistent=result.consistent, distance_m=result.distance_m,
        center_source=center_source, partner_center_source=partner_center,
        edges=tuple((p.target_neighbour, p.source_neighbour, p.edge_error_m, p.consistent) for p in pairs),
        target_edges_source=np.array([rotation @ target_graph.edges[by_target[p.target_neighbour]]
                                      for p in pairs]).reshape(-1, 3),
        source_edges=np.array([source_graph.edges[by_source[p.source_neighbour]] for p in pairs]).reshape(-1, 3),
    )
