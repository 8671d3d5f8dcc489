"""The rgbd odometry frame by frame against a recording's true poses: where it loses track, and why.

    python scripts/odometry_frames.py REC.mcap [--config '{"velocity_in_world": True}'] [--quiet] [--frames N]

Per frame: the true motion since the previous frame, the error of the estimated motion, the
frame's valid depth, its ORB keypoints, whether its colour counts as textured, the term it was
registered with, K when it became a keyframe, and which of the odometry's counters moved (feature
guess, promotion of the previous frame, rejection, a direction kept from the prediction). Then the
ATE (after SE(3) alignment) of the odometry alone and after loop closure, and the CPU time per
frame. The truth is the recording's true-pose channel, or its given poses when it has none (a TUM
import such as the 7-Scenes kitchen). --config: RgbdOdometryConfig fields as a Python literal.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import time

import numpy as np

from ndfa.io.recording import RecordingReader
from ndfa.trajectory.metrics import absolute_trajectory_error, rotation_angle
from ndfa.trajectory.open3d_threads import open3d_threads
from ndfa.trajectory.rgbd import RgbdOdometry
from ndfa.trajectory.session import rgbd_config_for

COUNTERS = {"feature_frames": "feat", "promoted_frames": "prom", "prediction_wins": "pwin",
            "feature_fallbacks": "fall", "rejected_frames": "rej", "starved_frames": "starv", "unseen_frames": "unseen",
            "faint_wall_frames": "faint"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--config", default="{}", help="RgbdOdometryConfig fields, a Python dict literal")
    parser.add_argument("--quiet", action="store_true", help="only the summary")
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames")
    args = parser.parse_args()
    overrides = ast.literal_eval(args.config)
    # With the recording's colour camera, as `ndfa poses` runs it (the 7-Scenes kitchen's colour is
    # not registered to its depth).
    config = rgbd_config_for(RecordingReader(args.recording).meta)
    odometry = RgbdOdometry(dataclasses.replace(config, **overrides))
    estimate, truth = [], []
    started = time.process_time()
    with open3d_threads():
        for index, frame in enumerate(RecordingReader(args.recording).frames()):
            if args.frames is not None and index >= args.frames:
                break
            before = {name: getattr(odometry, name) for name in COUNTERS}
            keyframes = len(odometry.keyframes)
            estimate.append(odometry.update(frame))
            truth.append(frame.pose_world_camera_true if frame.pose_world_camera_true is not None else frame.pose_world_camera)
            if index and not args.quiet:
                true_step = np.linalg.inv(truth[-2]) @ truth[-1]
                error = np.linalg.inv(true_step) @ np.linalg.inv(estimate[-2]) @ estimate[-1]
                view = odometry._previous[0] if odometry._previous else odometry.keyframes[-1].view
                moved = " ".join(short for name, short in COUNTERS.items() if getattr(odometry, name) != before[name])
                print(f"{index:5d} true {100 * np.linalg.norm(true_step[:3, 3]):5.1f} cm "
                      f"{np.degrees(rotation_angle(true_step[None, :3, :3])[0]):5.2f} deg  error "
                      f"{100 * np.linalg.norm(error[:3, 3]):6.2f} cm {np.degrees(rotation_angle(error[None, :3, :3])[0]):5.2f} deg"
                      f"  valid {view.valid_fraction:.2f} keypoints {len(view.features) if view.features is not None else -1:4d} textured {int(view.textured)}"
                      f" {odometry.terms[-1]:14s} {'K' if len(odometry.keyframes) > keyframes else ' '} {moved}")
        poses = odometry.finish()
    cpu_ms = 1000.0 * (time.process_time() - started) / len(estimate)
    alone = absolute_trajectory_error(np.array(estimate), np.array(truth))
    closed = absolute_trajectory_error(np.array(poses), np.array(truth))
    print(f"{args.recording} {overrides}: ATE {100 * closed.rmse_m:.2f} cm (max {100 * closed.max_m:.1f}; odometry alone "
          f"{100 * alone.rmse_m:.2f}), {cpu_ms:.0f} ms/frame CPU, {len(odometry.keyframes)} keyframes, "
          f"{odometry.loop_closures} loops, {odometry.unseen_frames} frames with unseen directions, "
          f"{odometry.faint_wall_frames} across a faint wall by hybrid")


if __name__ == "__main__":
    main()
