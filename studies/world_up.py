"""Measures `ndfa.trajectory.up.estimate_up` on the cases docs/world_up.md reports: the 7-Scenes
redkitchen slice against its gravity file, the simulator's z-up scenes as they are, tilted, and in
the first camera's frame (what odometry gives), and degenerate input.

    PYTHONPATH=$PWD python -m ndfa.cli ingest tum /work/shared/data/redkitchen_7scenes --out /tmp/rk.mcap \
        --intrinsics 585,585,320,240 --depth-scale 1000
    PYTHONPATH=$PWD python studies/world_up.py /tmp/rk.mcap /work/shared/data/redkitchen_7scenes/gravity-direction.txt \
        /work/baseline/paper/source.mcap /work/baseline/random1/source.mcap

Each line: case, frames given, ok, angle error to the true up (degrees), seconds of the estimate
(reading the frames not counted), and the estimate's one-line reason.
"""

import sys
import time

import numpy as np

from ndfa.core.frame import Frame
from ndfa.core.geometry import axis_angle_to_matrix, invert_pose, make_pose
from ndfa.io.recording import RecordingReader
from ndfa.trajectory.up import UpEstimate, angle_deg, estimate_up

TILTS = 5  # random roll/pitch tilts per simulated recording


def report(case: str, frames: list[Frame], true_up: np.ndarray | None, **kwargs) -> UpEstimate:
    """Estimate up from `frames` and print one line: the case, frames, ok, the angle to the true up,
    wall and CPU seconds of the estimate (the machine is shared: CPU time is the steadier number)."""
    cpu = time.process_time()
    estimate = estimate_up(frames, **kwargs)
    cpu = time.process_time() - cpu
    error = angle_deg(estimate.up_world, true_up) if estimate.ok and true_up is not None else float("nan")
    print(f"{case:46s} frames {estimate.frames:3d}  ok {estimate.ok!s:5s}  error {error:5.2f} deg  "
          f"{estimate.seconds:5.2f} s ({cpu:4.2f} s CPU)  {estimate.reason}", flush=True)
    return estimate


def with_poses(frames: list[Frame], transform) -> list[Frame]:
    """The frames with each pose replaced by transform(pose) (images shared)."""
    return [Frame(f.index, f.timestamp, f.rgb, f.depth, f.K, transform(f.pose_world_camera)) for f in frames]


def redkitchen(path: str, gravity_path: str) -> None:
    up = -np.loadtxt(gravity_path)  # the file gives gravity (down) in the poses' world: up is minus it
    reader = RecordingReader(path)
    for label, start, stop, step in [("first 3", 0, 3, 1), ("first 10", 0, 10, 1), ("first 50", 0, 50, 1),
                                     ("every 10th of 500", None, None, 10)]:
        frames = list(reader.frames(start=start, stop=stop, step=step))
        report(f"redkitchen {label}", frames, up)
    for start in range(0, len(reader), 100):
        report(f"redkitchen frames {start}-{start + 19}", list(reader.frames(start=start, stop=start + 20)), up)


def simulated(path: str, rng: np.random.Generator) -> None:
    reader = RecordingReader(path)
    name = path.split("/")[-2]
    frames = list(reader.frames(step=max(1, len(reader) // 50)))
    z = np.array([0.0, 0.0, 1.0])
    report(f"{name} as is (z-up)", frames, z)
    for _ in range(TILTS):
        angle = np.radians(rng.uniform(10.0, 40.0))
        tilt = axis_angle_to_matrix(angle * _horizontal_axis(rng))
        report(f"{name} tilted {np.degrees(angle):4.1f} deg", with_poses(frames, lambda pose: make_pose(tilt, np.zeros(3)) @ pose),
               tilt @ z)
    first = frames[0].pose_world_camera
    report(f"{name} first camera's frame", with_poses(frames, lambda pose: invert_pose(first) @ pose), first[:3, :3].T @ z)
    wobble = iter([axis_angle_to_matrix(np.radians(rng.uniform(5.0, 20.0)) * _horizontal_axis(rng)) for _ in frames])
    report(f"{name} each pose tilted 5-20 deg (must fail)",
           with_poses(frames, lambda pose: make_pose(next(wobble), np.zeros(3)) @ pose), None)
    report(f"{name} poses inverted (must fail)", with_poses(frames, invert_pose), None)


def _horizontal_axis(rng: np.random.Generator) -> np.ndarray:
    heading = rng.uniform(0.0, 2.0 * np.pi)
    return np.array([np.cos(heading), np.sin(heading), 0.0])


def degenerate(rng: np.random.Generator) -> None:
    K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
    upright = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # camera looks along world y
    wall = []
    for index in range(20):
        heading = axis_angle_to_matrix([0.0, 0.0, rng.uniform(0, 2 * np.pi)])
        depth = (2.0 + 0.003 * rng.normal(size=(480, 640))).astype(np.float32)  # a wall 2 m ahead
        wall.append(Frame(index, float(index), None, depth, K, make_pose(heading @ upright, np.zeros(3))))
    report("wall only (must fail)", wall, None)
    empty = [Frame(i, float(i), None, np.zeros((480, 640), np.float32), K, make_pose(upright, np.zeros(3))) for i in range(20)]
    report("no depth (must fail)", empty, None)
    report("no frames (must fail)", [], None)


def main() -> None:
    rng = np.random.default_rng(0)
    started = time.perf_counter()
    args = sys.argv[1:]
    if len(args) >= 2:
        redkitchen(args[0], args[1])
    for path in args[2:]:
        simulated(path, rng)
    degenerate(rng)
    print(f"total {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
