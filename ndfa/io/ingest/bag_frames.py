"""The frames of `ndfa ingest bag`: planned from the first pass's stamps, written in the second pass.

A frame is one depth image with the colour image and mask nearest in stamp within `max_dt`, the
CameraInfo nearest in stamp and the pose at the depth stamp. The second pass decodes only the
images some plan uses, in bag order, and writes each frame as soon as its parts are there.
"""

from __future__ import annotations

import bisect
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError

from ndfa.core.errors import IngestError, RecordingError
from ndfa.core.progress import Progress
from ndfa.io.ingest import PoseEstimator, ros_images
from ndfa.io.ingest.bag_poses import PoseLookup
from ndfa.io.ingest.bag_scan import BagScan
from ndfa.io.ingest.bag_topics import COMPRESSED_IMAGE, IMAGE
from ndfa.io.ingest.ros_images import ImageDecodeError, UnknownEncodingError
from ndfa.io.recording import Frame, RecordingWriter


@dataclass
class FramePlan:
    """One frame to write: which message of each role it is made of, its intrinsics and pose."""

    stamp: int
    parts: dict[str, int]  # role -> message ordinal within its topic
    K: np.ndarray
    image_size: tuple[int, int]
    pose: np.ndarray | None
    true_pose: np.ndarray | None


def plan_frames(scan: BagScan, chosen: dict[str, str], poses: PoseLookup, max_dt_ns: int) -> tuple[list[FramePlan], Counter]:
    """One plan per depth stamp that has its parts; the others counted by reason."""
    skipped: Counter = Counter()
    sorted_stamps = {role: _by_stamp(stamps) for role, stamps in scan.stamps.items()}
    skipped["unreadable depth message"] = scan.stamps["depth"].count(None)
    info_stamps = [info[0] for info in scan.infos]
    plans, last_stamp = [], None
    for stamp, ordinal in zip(*sorted_stamps["depth"]):
        if stamp == last_stamp:
            skipped["duplicate depth stamp"] += 1
            continue
        parts = {"depth": ordinal}
        for role in ("color", "mask"):
            if role in chosen:
                match = _nearest(sorted_stamps[role], stamp, max_dt_ns)
                if match is None:
                    parts = None
                    skipped[f"no {role} image within max_dt"] += 1
                    break
                parts[role] = match
        if parts is None:
            continue
        _, K, size = scan.infos[_nearest_index(info_stamps, stamp)]
        plans.append(FramePlan(stamp, parts, K, size, poses(stamp), scan.true_poses.get(stamp)))
        last_stamp = stamp
    return plans, skipped


def _by_stamp(stamps: list[int | None]) -> tuple[list[int], list[int]]:
    """The readable messages' stamps, sorted, and each one's ordinal (place in its topic)."""
    pairs = sorted((stamp, ordinal) for ordinal, stamp in enumerate(stamps) if stamp is not None)
    return [stamp for stamp, _ in pairs], [ordinal for _, ordinal in pairs]


def _nearest(stamps_ordinals: tuple[list[int], list[int]], stamp: int, max_dt_ns: int) -> int | None:
    """The ordinal of the message nearest to `stamp`, if within `max_dt_ns`."""
    stamps, ordinals = stamps_ordinals
    if not stamps:
        return None
    index = _nearest_index(stamps, stamp)
    return ordinals[index] if abs(stamps[index] - stamp) <= max_dt_ns else None


def _nearest_index(stamps: list[int], stamp: int) -> int:
    right = bisect.bisect_left(stamps, stamp)
    if right == 0:
        return 0
    if right == len(stamps):
        return len(stamps) - 1
    return right if stamps[right] - stamp < stamp - stamps[right - 1] else right - 1


_DECODERS = {
    ("depth", IMAGE): ros_images.depth_from_image, ("depth", COMPRESSED_IMAGE): ros_images.depth_from_compressed,
    ("color", IMAGE): ros_images.color_from_image, ("color", COMPRESSED_IMAGE): ros_images.color_from_compressed,
    ("mask", IMAGE): ros_images.mask_from_image, ("mask", COMPRESSED_IMAGE): ros_images.mask_from_compressed,
}
_UNDECODABLE = object()  # marks an image that was read but could not be decoded


def write_frames(reader: AnyReader, path: Path, out: Path, meta: dict, chosen: dict[str, str], plans: list[FramePlan],
                  skipped: Counter, scan: BagScan, estimate_poses: PoseEstimator | None,
                  on_progress: Progress | None) -> int:
    """Second pass: decode the images the plans use, in bag order, and write each frame as soon as
    its parts are there (frames in stamp order; only the images still waiting are held)."""
    if estimate_poses is None:
        for plan in plans:
            if plan.pose is None:
                skipped["no pose at the depth stamp"] += 1
        plans = [plan for plan in plans if plan.pose is not None]
    uses = Counter((role, ordinal) for plan in plans for role, ordinal in plan.parts.items())
    role_of = {topic: role for role, topic in chosen.items() if role != "info"}
    images: dict[tuple[str, int], object] = {}
    ordinals = Counter()
    next_plan, written, image_size = 0, 0, []
    try:
        with RecordingWriter(out, meta) as writer:
            if scan.ground_truth is not None:
                writer.write_ground_truth(scan.ground_truth)
            connections = [c for c in reader.connections if c.topic in role_of]
            for connection, _, data in reader.messages(connections=connections):
                role = role_of[connection.topic]
                key = (role, ordinals[role])
                ordinals[role] += 1
                if key not in uses:
                    continue
                images[key] = _decode(reader, role, connection.msgtype, data)
                while next_plan < len(plans) and all((r, o) in images for r, o in plans[next_plan].parts.items()):
                    plan = plans[next_plan]
                    next_plan += 1
                    parts = {}
                    for part in plan.parts.items():
                        parts[part[0]] = images[part] if uses[part] > 1 else images.pop(part)
                        uses[part] -= 1
                    written += _write_frame(writer, path, chosen, plan, parts, written, image_size, skipped,
                                            estimate_poses)
                    if on_progress is not None:
                        on_progress(next_plan, len(plans))
            skipped["image messages missing from the bag"] += len(plans) - next_plan
            if written == 0:
                reasons = ", ".join(f"{n} {why}" for why, n in skipped.items() if n) or "the bag has no frames"
                raise IngestError(f"{path}: no frame could be imported ({reasons})")
    except RecordingError as error:
        raise IngestError(f"{path}: cannot write {out}: {error}") from None
    for reason in [r for r, n in skipped.items() if n == 0]:
        del skipped[reason]
    return written


def _decode(reader: AnyReader, role: str, msgtype: str, data: bytes) -> object:
    try:
        return _DECODERS[role, msgtype](reader.deserialize(data, msgtype))
    except (AnyReaderError, ImageDecodeError, UnknownEncodingError):
        return _UNDECODABLE


def _write_frame(writer: RecordingWriter, path: Path, chosen: dict[str, str], plan: FramePlan, parts: dict[str, object],
                 index: int, image_size: list, skipped: Counter, estimate_poses: PoseEstimator | None) -> int:
    """Write one frame; 1 if written, 0 if skipped (and counted). `image_size` holds the first frame's."""
    broken = [role for role, image in parts.items() if image is _UNDECODABLE]
    if broken:
        skipped[f"undecodable {broken[0]} image"] += 1
        return 0
    depth = parts["depth"]
    for role in ("color", "mask"):
        if role in parts and parts[role].shape[:2] != depth.shape:
            raise IngestError(f"{path}: {role} images of {chosen[role]} are {parts[role].shape[1]}x{parts[role].shape[0]}, "
                              f"depth images of {chosen['depth']} {depth.shape[1]}x{depth.shape[0]}: ndfa needs depth "
                              "registered to the colour camera (e.g. an aligned_depth_to_color topic)")
    if plan.image_size[0] and plan.image_size != depth.shape:
        raise IngestError(f"{path}: CameraInfo {chosen['info']} is for {plan.image_size[1]}x{plan.image_size[0]} images, "
                          f"but the depth images of {chosen['depth']} are {depth.shape[1]}x{depth.shape[0]}; "
                          "choose the depth camera's CameraInfo with --info-topic")
    if image_size and image_size[0] != depth.shape:
        skipped["image size changed"] += 1
        return 0
    image_size[:] = [depth.shape]
    try:
        frame = Frame(index=index, timestamp=plan.stamp / 1e9, rgb=parts.get("color"), depth=depth, K=plan.K,
                      pose_world_camera=plan.pose if plan.pose is not None else np.eye(4),
                      instances=parts.get("mask"), pose_world_camera_true=plan.true_pose)
    except ValueError as error:  # NaN intrinsics in its CameraInfo, an impossible pose: skipped as undecodable
        skipped[f"invalid frame ({error})"] += 1
        return 0
    if estimate_poses is not None:
        frame.pose_world_camera = np.asarray(estimate_poses(frame), dtype=np.float64)
    writer.write_frame(frame)
    return 1
