"""A small offline tf buffer: the transforms of a whole bag, looked up at any stamp.

ROS describes where things are as a tree of coordinate frames, each edge a transform T_parent_child
published on /tf (moving, stamped) or /tf_static (fixed). A camera pose in the world is the chain
world -> ... -> camera through that tree, each moving edge interpolated to the image's stamp
(translation linearly, rotation by slerp), as tf2 does. Unlike tf2, the whole bag is known up
front, so there is no cache window: a lookup fails only before an edge's first sample or after its
last one (beyond `tolerance_ns`).

Frame names are compared without a leading "/" (ROS1 bags often write "/map").
ROS camera *optical* frames (`*_optical_frame`) already use the OpenCV axes ndfa uses (x right, y
down, z forward), so T_world_optical is `pose_world_camera` as it is; a camera *body* frame
(x forward, y left, z up) would need the fixed optical rotation, which bags publish on /tf_static.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.geometry import interpolate_pose, invert_pose, make_pose, matrix_from_quaternion_xyzw


class TfLookupError(LookupError):
    """A transform cannot be looked up: the frames do not connect, or the stamp is out of range."""


def frame_name(name: str) -> str:
    """A frame id as tf2 compares it: without a leading slash."""
    return name.lstrip("/")


@dataclass
class _Edge:
    """The samples of one parent -> child transform, sorted by stamp."""

    parent: str
    child: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    quaternions: list[np.ndarray] = field(default_factory=list)  # (x, y, z, w)
    _sorted: bool = True

    def add(self, stamp_ns: int, translation: np.ndarray, quaternion_xyzw: np.ndarray) -> None:
        if self.stamps and stamp_ns < self.stamps[-1]:
            self._sorted = False
        self.stamps.append(stamp_ns)
        self.translations.append(translation)
        self.quaternions.append(quaternion_xyzw / np.linalg.norm(quaternion_xyzw))

    def at(self, stamp_ns: int, tolerance_ns: int) -> np.ndarray:
        """T_parent_child at `stamp_ns`."""
        if self.static:
            return self._sample(-1)
        self._sort()
        stamps = self.stamps
        if stamp_ns < stamps[0] - tolerance_ns or stamp_ns > stamps[-1] + tolerance_ns:
            raise TfLookupError(f"tf {self.parent} -> {self.child} has samples from {stamps[0] / 1e9:.3f} to "
                                f"{stamps[-1] / 1e9:.3f} s, not at {stamp_ns / 1e9:.3f} s")
        right = bisect.bisect_left(stamps, stamp_ns)
        if right == 0 or right == len(stamps) or stamps[right] == stamp_ns:
            return self._sample(min(right, len(stamps) - 1))
        left = right - 1
        weight = (stamp_ns - stamps[left]) / (stamps[right] - stamps[left])
        return interpolate_pose(self._sample(left), self._sample(right), weight)

    def _sample(self, i: int) -> np.ndarray:
        """T_parent_child of the i-th sample."""
        return make_pose(matrix_from_quaternion_xyzw(self.quaternions[i]), self.translations[i])

    def _sort(self) -> None:
        if not self._sorted:
            order = np.argsort(self.stamps, kind="stable")
            self.stamps = [self.stamps[i] for i in order]
            self.translations = [self.translations[i] for i in order]
            self.quaternions = [self.quaternions[i] for i in order]
            self._sorted = True


class TransformBuffer:
    """Every transform of a bag: `add` them (any order), then `lookup(target, source, stamp)`.

    A frame has one parent (the tree of tf); a child published under two parents keeps the last one
    and is reported in `conflicts`.
    """

    def __init__(self, tolerance_ns: int = 0) -> None:
        self.tolerance_ns = tolerance_ns
        self._edges: dict[str, _Edge] = {}  # child -> edge to its parent
        self.conflicts: set[str] = set()
        self.invalid = 0  # samples left out: a zero or non-finite quaternion, a non-finite translation

    def add(self, parent: str, child: str, stamp_ns: int, translation: np.ndarray, quaternion_xyzw: np.ndarray,
            static: bool) -> None:
        translation, quaternion_xyzw = np.asarray(translation, float), np.asarray(quaternion_xyzw, float)
        with np.errstate(over="ignore", invalid="ignore"):
            length = float(np.linalg.norm(quaternion_xyzw))
        if not (1e-12 < length < np.inf and np.all(np.isfinite(translation))):
            self.invalid += 1  # as tf2 does, an impossible transform is refused, not normalised into NaN
            return
        parent, child = frame_name(parent), frame_name(child)
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent or edge.static != static:
            if edge is not None and edge.parent != parent:
                self.conflicts.add(child)
            edge = self._edges[child] = _Edge(parent, child, static)
        edge.add(stamp_ns, translation, quaternion_xyzw)

    def add_message(self, message: object, static: bool) -> None:
        """Add every transform of a tf2_msgs/TFMessage."""
        for transform in message.transforms:
            t, q = transform.transform.translation, transform.transform.rotation
            self.add(transform.header.frame_id, transform.child_frame_id, stamp_ns(transform.header.stamp),
                     np.array([t.x, t.y, t.z]), np.array([q.x, q.y, q.z, q.w]), static)

    def remove(self, child: str) -> None:
        """Forget the transform to `child` (a pose topic replaces what /tf says about that frame)."""
        self._edges.pop(frame_name(child), None)

    @property
    def frames(self) -> set[str]:
        return set(self._edges) | {edge.parent for edge in self._edges.values()}

    def __len__(self) -> int:
        return len(self._edges)

    def ancestors(self, frame: str) -> list[str]:
        """`frame`, its parent, its grandparent, ... up to the root of its tree."""
        chain, seen = [frame_name(frame)], {frame_name(frame)}
        while chain[-1] in self._edges:
            parent = self._edges[chain[-1]].parent
            if parent in seen:  # a cycle: tf forbids them, a broken bag may still hold one
                break
            chain.append(parent)
            seen.add(parent)
        return chain

    def connects(self, target: str, source: str) -> bool:
        return bool(set(self.ancestors(target)) & set(self.ancestors(source)))

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """T_target_source at `stamp_ns`: maps points in `source` coordinates to `target` coordinates."""
        up_from_target, up_from_source = self.ancestors(target), self.ancestors(source)
        common = next((frame for frame in up_from_source if frame in set(up_from_target)), None)
        if common is None:
            raise TfLookupError(self.describe_break(target, source))
        return invert_pose(self._to_ancestor(up_from_target, common, stamp_ns)) @ self._to_ancestor(
            up_from_source, common, stamp_ns)

    def _to_ancestor(self, chain: list[str], ancestor: str, stamp_ns: int) -> np.ndarray:
        """T_ancestor_frame for the frame chain[0]."""
        pose = np.eye(4)
        for frame in chain[: chain.index(ancestor)]:
            pose = self._edges[frame].at(stamp_ns, self.tolerance_ns) @ pose
        return pose

    def describe_break(self, target: str, source: str) -> str:
        """Why `target` and `source` do not connect: the chain each of them reaches."""
        up_from_target, up_from_source = self.ancestors(target), self.ancestors(source)
        return (f"frames {up_from_target[0]!r} and {up_from_source[0]!r} do not connect: "
                f"{' -> '.join(up_from_target)} and {' -> '.join(up_from_source)} lead up to different roots, and "
                f"no transform joins {up_from_target[-1]!r} and {up_from_source[-1]!r} "
                f"(frames in tf: {', '.join(sorted(self.frames)) or 'none'})")


def stamp_ns(stamp: object) -> int:
    """Nanoseconds of a ROS time (builtin_interfaces/Time; rosbags gives ROS1 times the same fields)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
