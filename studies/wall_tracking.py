"""What can track a camera walking along a bare wall (docs/odometry.md, "Where they break").

Three questions, on a recording with true poses (the office preset's seed 3 target, frames 126-147):

    python studies/wall_tracking.py terms REC.mcap 126 147 1     # each dense term from a start 3.7 cm off
    python studies/wall_tracking.py reloc REC.mcap 148,152,160 100,128,3   # features after the wall vs before
    python studies/wall_tracking.py model REC.mcap [--voxel 0.01] [--half]  # frame-to-model (Open3D tensor SLAM)

`terms`: for frames LO..HI, each registered against the frame GAP before it by point-to-plane and
by hybrid, starting from the true motion shifted by (3, -2, 1) cm, and again with the prediction
kept along the directions the depth cannot see; errors against the true motion.
`reloc`: whether ORB features of the frames after the wall find a motion to frames before it.
`model`: Open3D's VoxelBlockGrid TSDF with raycasting, hybrid frame-to-model tracking (no
features), its ATE against the true poses and CPU ms per frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ndfa.io.recording import RecordingReader
from ndfa.trajectory.degeneracy import keep_prediction_where_unseen
from ndfa.trajectory.features import estimate_motion
from ndfa.trajectory.metrics import absolute_trajectory_error
from ndfa.trajectory.rgbd import RgbdOdometryConfig
from ndfa.trajectory.rgbd_view import prepare_view, register_dense

PREDICTION_OFFSET_M = np.array([0.03, -0.02, 0.01])  # 3.7 cm: a constant-velocity guess a little off


def motion_error(estimate: np.ndarray, truth: np.ndarray) -> str:
    delta = np.linalg.inv(truth) @ estimate
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(delta[:3, :3]).as_rotvec()))
    return f"{100 * np.linalg.norm(delta[:3, 3]):5.2f} cm {angle:4.2f} deg"


def terms(path: str, low: int, high: int, gap: int) -> None:
    config = RgbdOdometryConfig()
    frames = [f for i, f in enumerate(RecordingReader(path).frames()) if low - gap <= i <= high]
    views = [prepare_view(frame, config) for frame in frames]
    for k in range(gap, len(frames)):
        before, now = frames[k - gap], frames[k]
        truth = np.linalg.inv(before.pose_world_camera_true) @ now.pose_world_camera_true
        prediction = truth.copy()
        prediction[:3, 3] += PREDICTION_OFFSET_M
        row = []
        for term in ("point-to-plane", "hybrid"):
            result, fitness = register_dense(views[k], views[k - gap], prediction, term, config)
            if result is None:
                row.append(f"{term}: failed")
                continue
            kept = keep_prediction_where_unseen(result, prediction, views[k].unseen_information,
                                                views[k].median_depth_m, 0.005)
            row.append(f"{term} {motion_error(result, truth)}, prediction kept where unseen "
                       f"{motion_error(kept, truth)}, fitness {fitness:.2f}")
        print(low - gap + k, " | ".join(row))


def reloc(path: str, after: list[int], before: range) -> None:
    config = RgbdOdometryConfig()
    frames = list(RecordingReader(path).frames())
    views = {i: prepare_view(frames[i], config) for i in set(after) | set(before)}
    for a in after:
        found = []
        for b in before:
            motion = estimate_motion(views[a].features, views[b].features, config.features)
            if motion is not None:
                truth = np.linalg.inv(frames[b].pose_world_camera_true) @ frames[a].pose_world_camera_true
                found.append(f"{b}: {100 * np.linalg.norm(motion.target_from_source[:3, 3] - truth[:3, 3]):.1f} cm")
        print(a, found or "no motion found")


def model(path: str, voxel_m: float, half: bool) -> None:
    import open3d as o3d

    slam = o3d.t.pipelines.slam
    device = o3d.core.Device("CPU:0")
    estimate, truth = [], []
    tracker = frame = raycast = None
    pose = np.eye(4)
    started = time.process_time()
    for i, recorded in enumerate(RecordingReader(path).frames()):
        depth = np.nan_to_num(recorded.depth, nan=0.0).astype(np.float32)
        rgb, K = recorded.rgb, recorded.K.copy()
        if half:
            depth, rgb = np.ascontiguousarray(depth[::2, ::2]), np.ascontiguousarray(rgb[::2, ::2])
            K[:2] /= 2
        height, width = depth.shape
        intrinsics = o3d.core.Tensor(K, o3d.core.Dtype.Float64)
        if tracker is None:
            tracker = slam.Model(voxel_m, 16, 40000, o3d.core.Tensor(np.eye(4)), device)
            frame = slam.Frame(height, width, intrinsics, device)
            raycast = slam.Frame(height, width, intrinsics, device)
        frame.set_data_from_image("depth", o3d.t.geometry.Image(depth[..., None]))
        frame.set_data_from_image("color", o3d.t.geometry.Image(np.ascontiguousarray(rgb.astype(np.float32) / 255)))
        if i > 0:
            tracker.synthesize_model_frame(raycast, 1.0, 0.1, 4.0, 8.0, True)
            result = tracker.track_frame_to_model(frame, raycast, 1.0, 4.0, 0.07, o3d.t.pipelines.odometry.Method.Hybrid)
            pose = pose @ result.transformation.numpy()
        tracker.update_frame_pose(i, o3d.core.Tensor(pose))
        tracker.integrate(frame, 1.0, 4.0, 8.0)
        estimate.append(pose.copy())
        truth.append(recorded.pose_world_camera_true)
    cpu_s = time.process_time() - started
    error = absolute_trajectory_error(np.array(estimate), np.array(truth))
    print(f"{path} frame-to-model, voxel {voxel_m} m, half {half}: ATE {100 * error.rmse_m:.2f} cm "
          f"(max {100 * error.max_m:.1f}), CPU {1000 * cpu_s / len(estimate):.0f} ms per frame")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    p = commands.add_parser("terms")
    p.add_argument("recording"), p.add_argument("low", type=int), p.add_argument("high", type=int)
    p.add_argument("gap", type=int)
    p = commands.add_parser("reloc")
    p.add_argument("recording"), p.add_argument("after"), p.add_argument("before")
    p = commands.add_parser("model")
    p.add_argument("recording"), p.add_argument("--voxel", type=float, default=0.01), p.add_argument("--half", action="store_true")
    args = parser.parse_args()
    if args.command == "terms":
        terms(args.recording, args.low, args.high, args.gap)
    elif args.command == "reloc":
        reloc(args.recording, [int(x) for x in args.after.split(",")], range(*map(int, args.before.split(","))))
    else:
        model(args.recording, args.voxel, args.half)


if __name__ == "__main__":
    main()
