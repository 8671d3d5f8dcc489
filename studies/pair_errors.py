"""How accurate the keyframe pair pass's registrations are: one odometry run as `ndfa detect`
prepares it, every candidate pair (each keyframe's CAP nearest older views that pass the pass's
tests) registered by coloured ICP and by point-to-plane ICP on 2 cm points, each compared with
the true relative pose; the chain's and the loops' edges alike; then the ATE with and without
the pairs (the graph re-solved from the loop-closed poses). docs/odometry.md, "Pairs where the
loops measured drift".

    .venv/bin/python studies/pair_errors.py REC [CAP]
"""
from __future__ import annotations

import dataclasses
import sys

import numpy as np

from ndfa.io.recording import RecordingReader
from ndfa.trajectory import keyframe_pairs as kp
from ndfa.trajectory.checks import InputCheckConfig, InputMonitor, fill_untracked
from ndfa.trajectory.metrics import absolute_trajectory_error
from ndfa.trajectory.open3d_threads import open3d_threads
from ndfa.trajectory.pose_graph import PoseEdge, PoseGraphConfig, optimize_pose_graph
from ndfa.trajectory.rgbd import RgbdOdometry
from ndfa.trajectory.session import rgbd_config_for


def error_cm(measured: np.ndarray, true: np.ndarray) -> float:
    return 100.0 * float(np.linalg.norm((np.linalg.inv(true) @ measured)[:3, 3]))


def run(path: str, cap: int) -> None:
    import open3d as o3d

    registration = o3d.pipelines.registration
    reader = RecordingReader(path)
    config = dataclasses.replace(rgbd_config_for(reader.meta), keyframe_pairs=False)
    monitor = InputMonitor(InputCheckConfig())
    fed, truth, timestamps, tracked = [], [], [], set()
    odometry = RgbdOdometry(config)
    with open3d_threads():
        for position, frame in enumerate(reader.frames()):
            timestamps.append(frame.timestamp)
            truth.append(frame.pose_world_camera_true if frame.pose_world_camera_true is not None else frame.pose_world_camera)
            if monitor.observe(frame).has_depth:
                tracked.add(position)
            if position in tracked or fed:
                fed.append(position)
                odometry.update(frame)
        keyframes = odometry.keyframes
        chained = [keyframe.pose for keyframe in keyframes]
        graph = PoseGraphConfig(max_correspondence_distance_m=config.loop_max_correction_m)
        closed = optimize_pose_graph(chained, odometry.edges, graph)
        kt = [truth[fed[keyframe.frame]] for keyframe in keyframes]
        views = [keyframe.view for keyframe in keyframes]
        capped = dataclasses.replace(config, pair_candidates=cap, pairs_per_frame=0.0, pair_voxel_m=0.02)
        pairs = kp.keyframe_pair_edges(views, closed, odometry.edges, capped)  # coloured ICP
        clouds = {index: kp._cloud(views[index], 0.02) for index in {e.source for e in pairs} | {e.target for e in pairs}}
        criteria = registration.ICPConvergenceCriteria(1e-6, 1e-6, config.pair_iterations)
        plane = []
        for edge in pairs:
            initial = np.linalg.inv(closed[edge.target]) @ closed[edge.source]
            result = registration.registration_icp(clouds[edge.source], clouds[edge.target], 0.04, initial,
                                                   registration.TransformationEstimationPointToPlane(), criteria)
            plane.append(np.asarray(result.transformation))

    def true_of(edge: PoseEdge) -> np.ndarray:
        return np.linalg.inv(kt[edge.target]) @ kt[edge.source]

    def ate(poses: list[np.ndarray]) -> float:
        frames: list[np.ndarray | None] = [None] * len(truth)
        for position, pose, keyframe in zip(fed, odometry._poses, odometry._keyframe_of, strict=True):
            if keyframe >= 0:
                pose = poses[keyframe] @ np.linalg.inv(chained[keyframe]) @ pose
            frames[position] = odometry._anchor @ pose if position in tracked else None
        return 100.0 * absolute_trajectory_error(np.array(fill_untracked(timestamps, frames)), np.array(truth)).rmse_m

    def summary(name: str, errors: list[float]) -> None:
        if errors:
            print(f"  {name}: {len(errors)}, error median {np.median(errors):.2f} cm, p90 {np.percentile(errors, 90):.2f} cm")

    print(f"{path}: {len(truth)} frames, {len(keyframes)} keyframes, {odometry.loop_closures} loops, {len(pairs)} pairs")
    summary("chain edges", [error_cm(e.target_from_source, true_of(e)) for e in odometry.edges if not e.loop])
    summary("loop edges", [error_cm(e.target_from_source, true_of(e)) for e in odometry.edges if e.loop])
    summary("graph's relative pose of the pairs",
            [error_cm(np.linalg.inv(closed[e.target]) @ closed[e.source], true_of(e)) for e in pairs])
    summary("pairs, coloured ICP", [error_cm(e.target_from_source, true_of(e)) for e in pairs])
    summary("pairs, point-to-plane", [error_cm(t, true_of(e)) for e, t in zip(pairs, plane, strict=True)])
    with_pairs = optimize_pose_graph(closed, list(odometry.edges) + pairs, graph) if pairs else closed
    drift = kp.loop_drift(chained, [keyframe.travelled_m for keyframe in keyframes], odometry.edges)
    print(f"  ATE without the pairs {ate(closed):.2f} cm, with them {ate(with_pairs):.2f} cm; loops' drift "
          f"{'-' if drift is None else f'{100 * drift:.2f} cm/m'} (the gate: {100 * config.pair_min_drift:.0f} cm/m)")


if __name__ == "__main__":
    run(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3)
