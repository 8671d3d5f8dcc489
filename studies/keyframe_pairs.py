"""One rgbd odometry run over a recording as `ndfa detect` prepares it (session.estimate_session_poses,
rgbd, the recording's colour camera), then finish() once per variant of the keyframe-pair pass:
true ATE, the pose-quality verdict without truth, CPU ms per frame (odometry + that finish).

    .venv/bin/python studies/keyframe_pairs.py [--only=off,cap3] REC [REC ...]

Variants: off (pairs off), default (the tree's: only where the loops measured drift, 0.1 pairs per
frame, 3 cm points), cap3 (every keyframe with its 3 nearest, 2 cm points, whatever the loops say: the
pass as odo30 measured it), cap3v3 (the same on 3 cm points).
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from ndfa.io.recording import RecordingReader
from ndfa.trajectory.checks import InputCheckConfig, InputMonitor, fill_untracked
from ndfa.trajectory.consistency import sketch_depth
from ndfa.trajectory.metrics import absolute_trajectory_error
from ndfa.trajectory.open3d_threads import open3d_threads
from ndfa.trajectory.quality import gather_evidence, judge
from ndfa.trajectory.rgbd import RgbdOdometry
from ndfa.trajectory.session import rgbd_config_for

ALWAYS = dict(keyframe_pairs=True, pair_min_drift=0.0, pairs_per_frame=0.0, pair_candidates=3)
VARIANTS = {"off": dict(keyframe_pairs=False), "default": {}, "cap3": dict(ALWAYS, pair_voxel_m=0.02),
            "cap3v3": dict(ALWAYS, pair_voxel_m=0.03)}


def run(path: str) -> None:
    reader = RecordingReader(path)
    base = rgbd_config_for(reader.meta)
    monitor = InputMonitor(InputCheckConfig())
    sketches, fed, truth, timestamps = {}, [], [], []
    odometry = RgbdOdometry(dataclasses.replace(base, **VARIANTS["off"]))
    cpu0 = time.process_time()
    with open3d_threads():
        for position, frame in enumerate(reader.frames()):
            timestamps.append(frame.timestamp)
            truth.append(frame.pose_world_camera_true if frame.pose_world_camera_true is not None else frame.pose_world_camera)
            has_depth = monitor.observe(frame).has_depth
            if has_depth:
                sketches[position] = sketch_depth(frame)
            if has_depth or fed:
                fed.append(position)
                odometry.update(frame)
        track_cpu = time.process_time() - cpu0
        for name, overrides in VARIANTS.items():
            odometry.config = dataclasses.replace(base, **overrides)
            c0 = time.process_time()
            estimate = odometry.finish()
            finish_cpu = time.process_time() - c0
            poses = [None] * len(truth)
            for position, pose in zip(fed, estimate):
                poses[position] = pose if position in sketches else None
            filled = fill_untracked(timestamps, poses)
            quality = judge(gather_evidence(filled, sketches, odometry, fed))
            ate = absolute_trajectory_error(np.array(filled), np.array(truth))
            ms = 1000.0 * (track_cpu + finish_cpu) / len(truth)
            print(f"{path} {name}: ATE {100 * ate.rmse_m:.2f} cm (max {100 * ate.max_m:.1f}), verdict {quality.verdict}"
                  f" [{quality.describe()}], {ms:.0f} ms/frame CPU "
                  f"(finish {1000.0 * finish_cpu / len(truth):.1f}), {len(odometry.keyframes)} keyframes, "
                  f"{odometry.loop_closures} loops", flush=True)


if __name__ == "__main__":
    if sys.argv[1].startswith("--only="):
        chosen = sys.argv.pop(1)[len("--only="):].split(",")
        VARIANTS = {k: v for k, v in VARIANTS.items() if k in chosen}
    for recording in sys.argv[1:]:
        run(recording)
