"""The camera poses of `ndfa ingest bag`: pose_world_camera at any stamp, from tf or a pose topic.

A pose topic (Odometry or PoseStamped) replaces what tf says about its child frame; the world frame
is the one given, else a REP 105 map frame the camera connects to, else the root of its tree.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ndfa.core.errors import IngestError
from ndfa.core.geometry import quaternion_xyzw_from_matrix
from ndfa.io.ingest.bag_scan import BagScan
from ndfa.io.ingest.tf_buffer import TfLookupError, frame_name

# Preferred world frames of a tf tree, in order (REP 105); otherwise the root of the camera's tree.
WORLD_FRAMES = ("map", "odom", "world")

PoseLookup = Callable[[int], np.ndarray | None]


def pose_lookup(path: Path, scan: BagScan, pose_topic: str | None, world: str | None, camera: str,
                 required: bool) -> tuple[PoseLookup, str | None]:
    """A function stamp -> pose_world_camera (None where there is none), and the world frame."""
    if pose_topic is None:
        return (lambda stamp: None), None
    buffer = scan.tf
    if pose_topic != "tf":
        if not scan.pose_samples:
            raise IngestError(f"{path}: the pose topic {pose_topic} has no readable messages")
        _, parent, child, _ = scan.pose_samples[0]
        # A PoseStamped carries no child frame: its pose is taken to be the camera's.
        child = child or camera
        buffer.remove(child)
        for stamp, _, _, pose in scan.pose_samples:
            buffer.add(parent, child, stamp, pose[:3, 3], quaternion_xyzw_from_matrix(pose[:3, :3]), static=False)
        world = world or frame_name(parent)
    if camera not in buffer.frames:
        if required:
            raise IngestError(f"{path}: the camera frame {camera!r} is not in tf (frames: "
                              f"{', '.join(sorted(buffer.frames)) or 'none'}); choose it with --camera-frame")
        return (lambda stamp: None), None
    if world is None:
        ancestors = buffer.ancestors(camera)
        # A map (odom, world) the camera connects to; else one it should connect to (the lookup then
        # names the break); else the root of the camera's own tree.
        world = next((f for f in WORLD_FRAMES if f in ancestors),
                     next((f for f in WORLD_FRAMES if f in buffer.frames), ancestors[-1]))
    world = frame_name(world)
    if not buffer.connects(world, camera):
        if required:
            raise IngestError(f"{path}: broken tf chain: {buffer.describe_break(world, camera)}")
        return (lambda stamp: None), None  # poses are estimated; the bag's only anchored them

    def lookup(stamp: int) -> np.ndarray | None:
        try:
            return buffer.lookup(world, camera, stamp)
        except TfLookupError:
            return None

    return lookup, world
