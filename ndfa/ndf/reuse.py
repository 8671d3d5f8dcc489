"""An object's NDF code reused while its view has barely changed since it was encoded (a speed
lever, off by default: `ReuseConfig`; measurements in docs/speed.md).

A camera moving past a static object sees it from nearly the same side in consecutive frames: on
`paper` the direction from the camera to an object turns by 3.3 degrees per frame (median), and
the shape codes of one object's views up to 15 degrees apart differ no more than two resamplings
of one view do (cosine median 0.95 against 0.957, centers 2.0 against 1.8 mm apart). An
observation that matches a view encoded in the last `ReuseConfig.max_gap_frames` frames (world
centroid within `shift_m`, view direction within `angle_deg`, point count within `points_ratio`)
takes that view's `ObjectCode` (world frame) instead of being encoded: the detector still gets one
measurement per observation, but fewer independent ones. Matching is always against the view
that was encoded, so a view that drifts slowly is encoded again once the drift adds up.

The paper encodes every observation; with `angle_deg` 0 (the default) so does the pipeline, which
hands a session's masked frames to `CodeReuse` otherwise (`PipelineConfig.reuse`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.ndf.encoder import NDFEncoder, ObjectCode


@dataclass(frozen=True)
class ReuseConfig:
    """When an observation takes the code of a view encoded before (module doc). angle_deg 0: never."""

    angle_deg: float = 0.0     # the views' directions from the camera to the centroid at most this apart
    shift_m: float = 0.01      # world centroids at most this apart
    points_ratio: float = 0.2  # point counts within this fraction of the encoded view's
    max_gap_frames: int = 3    # the encoded view was last matched within this many frames (calls)

    @property
    def enabled(self) -> bool:
        return self.angle_deg > 0


class CodeReuse:
    """One session's recently encoded views, in front of `NDFEncoder.encode_batch`; feed it the
    session's frames in order (a new session needs a new one: world frames differ)."""

    def __init__(self, encoder: NDFEncoder, config: ReuseConfig) -> None:
        self.encoder, self.config = encoder, config
        self._cos_angle = float(np.cos(np.radians(config.angle_deg)))
        self._views: list[_EncodedView] = []
        self._frame = 0
        self.reused = 0   # observations that took an earlier code
        self.encoded = 0  # observations encoded

    def encode(self, clouds: list[np.ndarray], pose_world_camera: np.ndarray, full_reconstruction: bool) -> list[ObjectCode]:
        """The codes of one frame's observations (camera frame, one pose), as `encode_batch`'s."""
        self._frame += 1
        self._views = [v for v in self._views if self._frame - v.last_frame <= self.config.max_gap_frames]
        pose = np.asarray(pose_world_camera, dtype=np.float64)
        centroids = np.array([np.asarray(c).mean(axis=0) for c in clouds]).reshape(-1, 3) @ pose[:3, :3].T + pose[:3, 3]
        rays = centroids - pose[:3, 3]
        rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
        codes: dict[int, ObjectCode] = {}
        todo: list[int] = []
        taken: set[int] = set()
        for k, cloud in enumerate(clouds):
            match = self._match(centroids[k], rays[k], len(cloud), full_reconstruction, taken)
            if match is None:
                todo.append(k)
                continue
            taken.add(match)
            self._views[match].last_frame = self._frame
            codes[k] = self._views[match].code
        fresh = self.encoder.encode_batch([clouds[k] for k in todo], [pose] * len(todo), full_reconstruction)
        for k, code in zip(todo, fresh):
            codes[k] = code
            # the newest view of a place replaces the older ones there
            self._views = [v for v in self._views if np.linalg.norm(v.centroid - centroids[k]) > self.config.shift_m]
            self._views.append(_EncodedView(centroids[k], rays[k], len(clouds[k]), full_reconstruction, code, self._frame))
        self.reused += len(clouds) - len(todo)
        self.encoded += len(todo)
        return [codes[k] for k in range(len(clouds))]

    def _match(self, centroid: np.ndarray, ray: np.ndarray, count: int, full: bool, taken: set[int]) -> int | None:
        config = self.config
        for index, view in enumerate(self._views):
            if (index not in taken and (view.full or not full)
                    and np.linalg.norm(view.centroid - centroid) <= config.shift_m
                    and float(view.ray @ ray) >= self._cos_angle
                    and abs(count - view.count) <= config.points_ratio * view.count):
                return index
        return None


@dataclass
class _EncodedView:
    centroid: np.ndarray   # world
    ray: np.ndarray        # unit, camera to centroid, world
    count: int             # points of the observation
    full: bool             # its reconstruction decoded in full (`encode_batch`'s full_reconstruction)
    code: ObjectCode
    last_frame: int        # the call that encoded or last reused it
