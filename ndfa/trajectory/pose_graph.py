"""Loop closure: the keyframes of one session as an Open3D pose graph, optimised once at the end.

Why: frame-to-keyframe odometry drifts a little at every keyframe, and nothing within the
odometry can see that drift. When the camera comes back to a place it saw long ago, registering
the new keyframe directly to the old one measures the accumulated drift; spreading that correction
over the keyframes in between (Levenberg-Marquardt on the graph) is what removes it.

Edge convention (Open3D's): an edge from `source` to `target` holds T_target_source, the pose of
the source keyframe in the target keyframe's frame (what registering source onto target returns),
and its 6x6 information matrix in Open3D's (rotation, translation) order. Odometry edges join
consecutive keyframes and are trusted; loop edges are `uncertain`, so the optimiser may prune a
wrong one (its line process) instead of bending the whole trajectory to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PoseEdge:
    """A measured relative pose between two keyframes (indices into the keyframe list)."""

    source: int
    target: int
    target_from_source: np.ndarray  # (4, 4) T_target_source
    information: np.ndarray  # (6, 6)
    loop: bool = False


@dataclass(frozen=True)
class PoseGraphConfig:
    """Settings of the global optimisation (Open3D's `GlobalOptimizationOption`).

    max_correspondence_distance_m: Open3D scales the line process of the uncertain (loop) edges by
        its square: a loop edge whose residual in the odometry's graph is much larger is pruned. A
        verified loop may correct the odometry's drift by up to `loop_max_correction_m` (rgbd.py),
        so this is that, not the registrations' inlier distance (with 7 cm a 25 cm drift was never
        corrected).
    edge_prune_threshold: loop edges whose line-process weight falls below this are dropped as wrong.
    preference_loop_closure: weight of the loop edges against the odometry edges (Open3D's default).
    max_iterations: Levenberg-Marquardt iteration cap.
    """

    max_correspondence_distance_m: float = 0.3
    edge_prune_threshold: float = 0.25
    preference_loop_closure: float = 1.0
    max_iterations: int = 100


def optimize_pose_graph(poses_world_keyframe: list[np.ndarray], edges: list[PoseEdge],
                        config: PoseGraphConfig = PoseGraphConfig()) -> list[np.ndarray]:
    """The keyframe poses (4, 4, camera-to-world) after Levenberg-Marquardt on the graph of
    `edges`, with the first keyframe held fixed. Without loop edges the odometry already satisfies
    every edge, so the poses come back unchanged (no optimisation is run)."""
    import open3d as o3d

    if not any(edge.loop for edge in edges) or len(poses_world_keyframe) < 2:
        return [np.array(pose, dtype=float) for pose in poses_world_keyframe]
    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for pose in poses_world_keyframe:
        graph.nodes.append(registration.PoseGraphNode(np.asarray(pose, dtype=float)))
    for edge in edges:
        graph.edges.append(registration.PoseGraphEdge(
            edge.source, edge.target, np.asarray(edge.target_from_source, dtype=float),
            np.asarray(edge.information, dtype=float), uncertain=edge.loop))
    criteria = registration.GlobalOptimizationConvergenceCriteria()
    criteria.max_iteration = config.max_iterations
    option = registration.GlobalOptimizationOption(
        max_correspondence_distance=config.max_correspondence_distance_m,
        edge_prune_threshold=config.edge_prune_threshold,
        preference_loop_closure=config.preference_loop_closure, reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        registration.global_optimization(graph, registration.GlobalOptimizationLevenbergMarquardt(), criteria, option)
    return [np.array(node.pose) for node in graph.nodes]
