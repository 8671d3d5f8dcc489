"""A last pass after loop closure: every pair of keyframes that look at the same place, registered
directly and added to the pose graph, which is then optimised again.

Why: the odometry joins each keyframe to the one before it, and loop closure a new keyframe to at
most `loop_candidates` old ones far back along the path, so each keyframe's pose rests on one or
two registrations and their errors add up between loops (the 7-Scenes kitchen: 28 keyframes, 33
edges, each 0.5-5 cm off the given relative pose). Most keyframes see the same surfaces as several
others (134 more pairs there); measuring those too averages the registrations' errors instead of
chaining them (docs/odometry.md, "A last pass over the keyframe pairs").

Coloured ICP (Park et al., ICCV 2017: point-to-plane distances and the colour's gradient along
the surface, on points thinned to a voxel grid) registers the pairs; the odometry's dense terms
(projective association at 320 px) did worse on the kitchen's pairs (docs/odometry.md). Guard:
facing a bare wall, or a wall and a floor, depth cannot see the slide along them, and
point-to-plane slid 10-29 cm on such pairs of a bare synthetic room; a pair is registered only when
the depth of both keyframes sees every direction (the wide-baseline plane term the odometry uses
for the same question: `sees_every_direction`), colour or not. A pair that lands far
from where the loop-closed graph puts it fell into another minimum and is left out; the pass's
edges are uncertain, so the optimiser may still prune a wrong one.
"""

from __future__ import annotations

import math

import numpy as np

from ndfa.trajectory.degeneracy import depth_degeneracy
from ndfa.trajectory.pose_graph import PoseEdge, PoseGraphConfig, optimize_pose_graph
from ndfa.trajectory.rgbd_config import RgbdOdometryConfig
from ndfa.trajectory.rgbd_view import View


def sees_every_direction(view: View, config: RgbdOdometryConfig) -> bool:
    """Whether the view's depth pins all six directions of motion (no eigenvalue of its
    wide-baseline plane term below `unseen_ratio` of the largest: `degeneracy.keep_prediction_where_unseen`)."""
    return depth_degeneracy(view.unseen_information, view.median_depth_m) >= config.unseen_ratio


def loop_drift(odometry: list[np.ndarray], travelled_m: list[float], edges: list[PoseEdge]) -> float | None:
    """The median over the loop `edges` of how far each disagrees with the `odometry` poses
    (translation, metres) per metre travelled between its two keyframes (`travelled_m`, from the
    first); None without a loop edge."""
    rates = []
    for edge in edges:
        if edge.loop:
            chained = np.linalg.inv(odometry[edge.target]) @ odometry[edge.source]
            residual = float(np.linalg.norm((np.linalg.inv(edge.target_from_source) @ chained)[:3, 3]))
            rates.append(residual / max(abs(travelled_m[edge.source] - travelled_m[edge.target]), 1e-6))
    return float(np.median(rates)) if rates else None


def keyframe_pair_edges(views: list[View], poses: list[np.ndarray], edges: list[PoseEdge],
                        config: RgbdOdometryConfig, travelled_m: list[float] | None = None,
                        frames: int = 0) -> list[PoseEdge]:
    """Loop edges between the keyframes (`views`, their loop-closed `poses`, first camera's frame)
    that look at the same place (view centres within `loop_radius_m`, axes within
    `loop_angle_deg`), are not already joined by one of `edges`, and whose depth sees every
    direction; each registered by coloured ICP from the relative pose the graph gives them. With
    `travelled_m` (each keyframe's path length) and `frames` (the session's), at most
    `pairs_per_frame` per frame, the pairs that span the longest path first."""
    joined = {(min(edge.source, edge.target), max(edge.source, edge.target)) for edge in edges}
    pinned = [sees_every_direction(view, config) for view in views]
    centres = [pose[:3, 3] + view.median_depth_m * pose[:3, 2] for view, pose in zip(views, poses, strict=True)]
    pairs: list[tuple[int, int]] = []
    for new in range(len(views)):
        candidates = []
        for old in range(new - 1):
            if (old, new) in joined or not (pinned[old] and pinned[new]):
                continue
            axes = float(np.clip(poses[old][:3, 2] @ poses[new][:3, 2], -1.0, 1.0))
            distance = float(np.linalg.norm(centres[new] - centres[old]))
            if distance <= config.loop_radius_m and math.degrees(math.acos(axes)) <= config.loop_angle_deg:
                candidates.append((distance, old))
        # The nearest views first: they overlap most; a cap keeps the pass linear in the keyframes.
        pairs.extend((new, old) for _, old in sorted(candidates)[:config.pair_candidates or None])
    if travelled_m is not None and frames and config.pairs_per_frame:
        # The longest spans first: the chain's drift between them is the largest.
        pairs.sort(key=lambda pair: -(travelled_m[pair[0]] - travelled_m[pair[1]]))
        pairs = pairs[:max(1, int(config.pairs_per_frame * frames))]
    added: list[PoseEdge] = []
    clouds: dict[int, object] = {}  # by keyframe, built when a pair first needs it
    for new, old in pairs:
        initial = np.linalg.inv(poses[old]) @ poses[new]
        edge = _register_pair(views, new, old, initial, config, clouds)
        if edge is not None and np.linalg.norm(edge.target_from_source[:3, 3] - initial[:3, 3]) <= config.pair_max_correction_m:
            added.append(edge)
    return added


def _register_pair(views: list[View], new: int, old: int, initial: np.ndarray, config: RgbdOdometryConfig,
                   clouds: dict[int, object]) -> PoseEdge | None:
    """The loop edge T_old_new by coloured ICP (point-to-plane where either view has no colour)
    from `initial`, or None when too little of `new` overlaps `old` (`loop_min_fitness`)."""
    import open3d as o3d

    registration = o3d.pipelines.registration
    for index in (new, old):
        if index not in clouds:
            clouds[index] = _cloud(views[index], config.pair_voxel_m)
    coloured = views[new].textured and views[old].textured
    distance = 2.0 * config.pair_voxel_m
    estimation = (registration.TransformationEstimationForColoredICP() if coloured
                  else registration.TransformationEstimationPointToPlane())
    criteria = registration.ICPConvergenceCriteria(1e-6, 1e-6, config.pair_iterations)
    icp = registration.registration_colored_icp if coloured else registration.registration_icp
    try:
        result = icp(clouds[new], clouds[old], distance, initial, estimation, criteria)
    except RuntimeError:  # Open3D raises when there are no correspondences
        return None
    if result.fitness < config.loop_min_fitness:
        return None
    measured = np.asarray(result.transformation)
    information = registration.get_information_matrix_from_point_clouds(clouds[new], clouds[old], distance, measured)
    return PoseEdge(new, old, measured, np.asarray(information), loop=True)


def _cloud(view: View, voxel_m: float) -> object:
    """The view's points (camera frame) with colour, thinned to one per `voxel_m` cube, with normals
    facing the camera: Open3D's legacy point cloud, as its ICP wants it."""
    import open3d as o3d

    depth = view.rgbd.depth.as_tensor().numpy()[..., 0]
    colour = view.rgbd.color.as_tensor().numpy()
    K = view.K.numpy()
    rows, cols = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[rows, cols].astype(np.float64)
    points = np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.colors = o3d.utility.Vector3dVector(colour[rows, cols].astype(np.float64) / 255.0)
    cloud = cloud.voxel_down_sample(voxel_m)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel_m, max_nn=30))
    cloud.orient_normals_towards_camera_location(np.zeros(3))
    return cloud


def refine_with_keyframe_pairs(views: list[View], poses: list[np.ndarray], edges: list[PoseEdge],
                               config: RgbdOdometryConfig, odometry: list[np.ndarray] | None = None,
                               travelled_m: list[float] | None = None, frames: int = 0) -> list[np.ndarray]:
    """The keyframes' poses after the graph of `edges` and the pairs' edges is optimised from the
    loop-closed `poses` (unchanged when no pair qualifies, or when the loops measured less drift
    of the `odometry` poses than `pair_min_drift`; `travelled_m`: each keyframe's path length)."""
    if config.pair_min_drift > 0.0:
        drift = None if odometry is None or travelled_m is None else loop_drift(odometry, travelled_m, edges)
        if drift is None or drift < config.pair_min_drift:
            return [np.array(pose, dtype=float) for pose in poses]
    added = keyframe_pair_edges(views, poses, edges, config, travelled_m, frames)
    if not added:
        return [np.array(pose, dtype=float) for pose in poses]
    graph = PoseGraphConfig(max_correspondence_distance_m=config.loop_max_correction_m)
    return optimize_pose_graph(poses, list(edges) + added, graph)
