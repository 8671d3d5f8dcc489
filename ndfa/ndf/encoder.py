"""Inference: partial object point clouds -> `ObjectCode` (shape code, world center, latent z,
mean occupancy, reconstruction, handle heading). Pure computation: no files are read here except the weights.

Each observation is resampled to the model's point count, centred on its mean (the translation),
encoded, and decoded on a grid around the predicted center; everything is moved to the world
frame with the camera pose. The network runs in ONNX Runtime when it is installed, else in torch
(`ndfa.ndf.runtime`, `EncoderConfig.runtime`); `NDFEncoder.runtime.name` says which.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from ndfa.core.conventions import UNKNOWN_CATEGORY, world_up
from ndfa.core.errors import ModelError
from ndfa.core.geometry import transform_points
from ndfa.ndf.checkpoint import load_model
from ndfa.ndf.heading import frame_weights_of, handle_heading
from ndfa.ndf.runtime import make_runtime

WEIGHTS_DIR = Path(__file__).parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "ndf_mugs.pt"
CENTER_METHODS = ("head", "reconstruction", "weighted")
MIN_POINTS = 10  # fewer points than this carry too little shape to encode
# Observations per network call: the decoder's nearest-point search holds a [batch, queries,
# points] array, which for 1,000 views on `ndfa ndf-eval`'s 20^3 grid took more than 20 GB.
MAX_BATCH = 64


@dataclass(frozen=True)
class ObjectCode:
    """One observation as the NDF sees it. Frames: world (via the camera pose)."""

    shape_code: np.ndarray       # [D] rotation-invariant shape descriptor
    center_world: np.ndarray     # [3] center of the completed full shape, metres
    z: np.ndarray                # [k, 3] equivariant latent, rotated into the world frame
    mean_occupancy: float        # mean predicted occupancy over the reconstruction (confidence)
    reconstruction: np.ndarray   # [M, 3] grid points with occupancy > v0, world frame
    # The handle's azimuth about world up and how sure the network is of it (`ndfa.ndf.heading`):
    # NaN and 0 for a model without the trained frame decoder.
    heading_rad: float = float("nan")
    heading_strength: float = 0.0
    # The most probable of the model's categories and its probability (`NDFEncoder.categories`);
    # `UNKNOWN_CATEGORY` and NaN for a model without a category head (NDF v2).
    category: str = UNKNOWN_CATEGORY
    category_probability: float = float("nan")


FINE_GRID_RESOLUTION = 20  # the reconstruction grid of `ndfa ndf-eval` and the model card


@dataclass(frozen=True)
class EncoderConfig:
    """How observations are encoded and their reconstruction decoded.

    coarse_threshold: the grid is decoded coarse to fine (as Occupancy Networks' MISE does): first
        every other point per axis, then only the fine points next to a coarse point whose
        occupancy exceeds this; the others are taken as empty. Decoding was most of the encoding
        time, and a mug fills a fraction of the cube around it. On 470 views of the `paper` scene
        (12^3 grid) this took 17.6 instead of 31.0 ms per frame; which views reconstruct empty
        did not change, 42 reconstructions lost a few thin-walled points (mean occupancy within
        0.04). 0 decodes every point.
    grid_resolution: 12^3 (2 cm cells) for the detector, which uses only the reconstruction's mean
        occupancy (and the sinks show it): the grid is most of the encoding time, about 4.7x less
        than at `FINE_GRID_RESOLUTION`, which `ndfa ndf-eval` and the model card's reconstruction
        figures use.
    runtime: where the network runs (`ndfa.ndf.runtime`): "torch" (the reference), "onnxruntime"
        or "auto" (the default: ONNX Runtime when installed, else torch). ONNX Runtime's encoding is
        1.6x faster on the `paper` scene (docs/speed.md); it breaks near-ties of the
        nearest-neighbour search differently, so codes agree to a cosine >= 0.9999 and centers to
        0.2 mm but mean occupancy only to ~0.06. With v1 weights that let one kitchen segment
        through the objectness gate; with NDF v2 both runtimes give the same reports on the
        seven scenes and the five rotated ones, and the kitchen halves report nothing with ONNX
        Runtime (2026-12-02, docs/speed.md).
    probe_radius_m: where the grid is decoded only as far as decisions need
        (`NDFEncoder.encode_batch(full_reconstruction=False)`), the coarse points within this
        distance of the predicted center are decoded first, and the other coarse points only for
        observations with none of them above v0: a mug's wall passes within a few cm of its
        center. Speed only: which reconstructions are empty does not depend on it. 0.06 m: 17 of
        the 216 coarse points, one of them above v0 in 99.7 % of the `paper` views with any coarse
        point above it (docs/speed.md).
    threads: ONNX Runtime's intra-op threads (torch's are process-wide: `torch.set_num_threads`).
        1: the pass is then one thread and keeps its speed beside another busy process on a
        2-core machine (docs/speed.md).
    n_points, knn: points per observation and the encoder's neighbours per point, instead of the
        checkpoint's (None: the checkpoint's, 256 and 12 for the shipped weights). Fewer is faster
        (the encoder is linear in both, its neighbour search quadratic in the points); keeping
        knn / n_points keeps the local layer's neighbourhood at the size it was trained on. With
        224 and 10 the shipped NDF's centers on `paper` are within the resampling's own noise
        and encoding takes 13 % less CPU; the detector's reports move as with another resampling
        seed (docs/speed.md, 2026-12-03 afternoon), so this is not the default.
    """

    v0: float = 0.5                  # occupancy threshold of the reconstruction
    center: str = "head"             # head | reconstruction | weighted (see `ndfa ndf-eval`)
    grid_resolution: int = 12        # reconstruction grid cells per axis
    grid_half_extent_m: float = 0.11  # the grid spans +-this around the predicted center
    coarse_threshold: float = 0.05
    probe_radius_m: float = 0.06
    seed: int = 0                    # of the point resampling, so encoding is deterministic
    runtime: str = "auto"
    threads: int = 1
    n_points: int | None = None
    knn: int | None = None


class NDFEncoder:
    """The trained NDF as a function of observations; loads the shipped weights by default."""

    def __init__(self, weights: Path | None = None, config: EncoderConfig = EncoderConfig()):
        if config.center not in CENTER_METHODS:
            raise ModelError(f"unknown center method {config.center!r}; expected one of {CENTER_METHODS}")
        self.weights = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        self.model, extra = load_model(self.weights)
        self.model.eval()
        if config.n_points is not None and config.n_points < MIN_POINTS or config.knn is not None and config.knn < 1:
            raise ModelError(f"encoding needs n_points >= {MIN_POINTS} and knn >= 1, got {config.n_points} and {config.knn}")
        self.n_points = config.n_points or int(extra.get("n_points", 400))
        if config.knn is not None:
            self.model.encoder.knn = config.knn  # read by the encoder network and its export
        self.config = config
        self.runtime = make_runtime(self.model, self.n_points, config.runtime, config.threads)
        self._frame_weights = frame_weights_of(self.model)
        # The categories its head tells apart (NDF v3); none: every object's is `UNKNOWN_CATEGORY`.
        self.categories: tuple[str, ...] = tuple(self.model.config.categories)
        axis = np.linspace(-1.0, 1.0, config.grid_resolution, dtype=np.float32) * config.grid_half_extent_m
        self._grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
        n = config.grid_resolution
        self._coarse = np.arange(n ** 3).reshape(n, n, n)[::2, ::2, ::2].ravel()  # every other point per axis
        probe = np.linalg.norm(self._grid[self._coarse], axis=1) <= config.probe_radius_m
        self._probe, self._coarse_rest = self._coarse[probe], self._coarse[~probe]
        # Which points an observation keeps depends on its point count only (`resample`): drawn
        # once per count instead of a generator per observation (docs/speed.md).
        self._resample_index = lru_cache(maxsize=4096)(self._draw_resample_index)

    def encode(self, points_camera: np.ndarray, pose_world_camera: np.ndarray) -> ObjectCode:
        """One observation: points [N, 3] in the camera frame, camera-to-world pose [4, 4]."""
        return self.encode_batch([points_camera], [pose_world_camera])[0]

    def encode_batch(self, clouds: list[np.ndarray], poses_world_camera: list[np.ndarray],
                     full_reconstruction: bool = True) -> list[ObjectCode]:
        """Several observations at once (faster per observation than one by one), at most
        `MAX_BATCH` per network call.

        full_reconstruction False: the grid is decoded only as far as telling an empty
        reconstruction from a non-empty one needs (`_grid_occupancy`): the coarse points near the
        center, the other coarse ones only where none of those exceeds v0, the fine ones only where
        no coarse point does. `mean_occupancy` and `reconstruction` are then those of the points
        decoded; whether a reconstruction is empty is the same either way. For callers that use no
        more than that (`ndfa.pipeline` without sinks, on masked frames); the fine pass was most of
        the decoding."""
        if len(clouds) != len(poses_world_camera):
            raise ModelError(f"{len(clouds)} point clouds but {len(poses_world_camera)} camera poses")
        if len(clouds) > MAX_BATCH:
            for i, cloud in enumerate(clouds):  # errors name the observation's index in `clouds`
                _checked_cloud(cloud, i)
            return [code for start in range(0, len(clouds), MAX_BATCH)
                    for code in self.encode_batch(clouds[start:start + MAX_BATCH],
                                                  poses_world_camera[start:start + MAX_BATCH], full_reconstruction)]
        if not clouds:
            return []
        points = np.stack([self.resample(_checked_cloud(c, i)) for i, c in enumerate(clouds)])
        centred, up, centroids = self._inputs(points, poses_world_camera)
        z, codes, offsets, probabilities = self.runtime.encode(centred, up, centroids[:, 0].astype(np.float32))
        query_points = offsets[:, None, :] + self._grid[None]  # around each predicted center
        occupancy = self._grid_occupancy(z, query_points, centred, full_reconstruction)

        results = []
        for i, pose in enumerate(poses_world_camera):
            inside = occupancy[i] > self.config.v0
            center_local = self._center(offsets[i], query_points[i], occupancy[i], inside)
            rotation = np.asarray(pose)[:3, :3]
            z_world = z[i] @ rotation.T
            heading = handle_heading(z_world, self._frame_weights)
            category, probability = UNKNOWN_CATEGORY, float("nan")
            if probabilities is not None:
                likeliest = int(np.argmax(probabilities[i]))
                category, probability = self.categories[likeliest], float(probabilities[i, likeliest])
            results.append(ObjectCode(
                shape_code=codes[i],
                center_world=transform_points(pose, (centroids[i, 0] + center_local)[None])[0],
                z=z_world,
                mean_occupancy=float(occupancy[i][inside].mean()) if inside.any() else 0.0,
                reconstruction=transform_points(pose, query_points[i][inside] + centroids[i, 0]),
                heading_rad=heading.angle_rad,
                heading_strength=heading.strength,
                category=category,
                category_probability=probability,
            ))
        return results

    @staticmethod
    def _inputs(points: np.ndarray, poses_world_camera: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The network's inputs from resampled clouds `[B, n, 3]` (camera frame): the centred
        clouds (float32), world up in each camera's frame `[B, 3]` (float32) and the centroids
        `[B, 1, 3]` (float64; the view rays)."""
        # Centre in float64: float32 points a few metres from the camera lose digits otherwise.
        centroids = points.mean(axis=1, keepdims=True)
        centred = (points - centroids).astype(np.float32)
        # The cues: world up seen from each camera, and each view's direction from its camera.
        up_world = world_up()  # the world is z-up by convention (`ndfa.core.conventions`)
        up = np.stack([np.asarray(pose)[:3, :3].T @ up_world for pose in poses_world_camera]).astype(np.float32)
        return centred, up, centroids

    @torch.inference_mode()
    def latent(self, points: np.ndarray, poses_world_camera: list[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """z `[B, k, 3]` of resampled clouds `[B, n, 3]` (camera frame), the centred clouds the
        model saw and their centroids `[B, 1, 3]` (float64)."""
        centred, up, centroids = self._inputs(points, poses_world_camera)
        z = self.model.encode(torch.from_numpy(centred), torch.from_numpy(up),
                              torch.from_numpy(centroids[:, 0].astype(np.float32)))
        return z, torch.from_numpy(centred), centroids

    def _grid_occupancy(self, z: np.ndarray, queries: np.ndarray, points: np.ndarray, full: bool = True) -> np.ndarray:
        """Occupancy `[B, G^3]` of the grid queries, decoded coarse to fine (see `EncoderConfig`);
        not `full`: only until each observation has a point above v0 (not empty) or has none in
        the whole grid (empty): first the coarse points near the center (`probe_radius_m`), then
        the other coarse ones, then the fine ones around the highest coarse point, then the rest."""
        if self.config.coarse_threshold <= 0:
            return self.runtime.occupancy(z, queries, points)
        n, v0 = self.config.grid_resolution, self.config.v0
        batch, coarse = len(queries), self._coarse
        coarse_shape = (batch, *[len(range(0, n, 2))] * 3)
        occupancy = np.zeros((batch, n ** 3), dtype=np.float32)
        if full:
            occupancy[:, coarse] = self.runtime.occupancy(z, np.ascontiguousarray(queries[:, coarse]), points)
        else:
            occupancy[:, self._probe] = self.runtime.occupancy(z, np.ascontiguousarray(queries[:, self._probe]), points)
            rest = np.zeros((batch, n ** 3), dtype=bool)
            rest[np.ix_(~(occupancy > v0).any(axis=1), self._coarse_rest)] = True
            self._decode_points(occupancy, rest, z, queries, points)
            if (occupancy > v0).any(axis=1).all():
                return occupancy  # every one decided: none is empty
        near = self._fine_near(occupancy[:, coarse].reshape(coarse_shape) > self.config.coarse_threshold)
        near[:, coarse] = False  # already decoded
        if not full:
            undecided = ~(occupancy[:, coarse] > v0).any(axis=1)  # else: not empty
            near[~undecided] = False
            highest = np.zeros(coarse_shape, dtype=bool)
            highest.reshape(batch, -1)[undecided, occupancy[undecided][:, coarse].argmax(axis=1)] = True
            first = near & self._fine_near(highest)
            self._decode_points(occupancy, first, z, queries, points)
            near &= ~first
            near[(occupancy > v0).any(axis=1)] = False
        self._decode_points(occupancy, near, z, queries, points)
        return occupancy

    def _fine_near(self, coarse_mask: np.ndarray) -> np.ndarray:
        """`[B, G^3]`: the fine grid points within one coarse step of a point of `coarse_mask`
        `[B, c, c, c]`: dilate, then upsample (fine index i lies between coarse i // 2 and i // 2 + 1)."""
        dilated = binary_dilation(coarse_mask, structure=np.ones((1, 3, 3, 3), dtype=bool))
        up = np.arange(self.config.grid_resolution) // 2
        near: np.ndarray = dilated[:, up][:, :, up][:, :, :, up].reshape(len(coarse_mask), -1)
        return near

    def _decode_points(self, occupancy: np.ndarray, chosen: np.ndarray, z: np.ndarray, queries: np.ndarray,
                     points: np.ndarray) -> None:
        """Decode the grid points `chosen` `[B, G^3]` into `occupancy`, as one padded batch of the
        observations with any (each padded with its first point)."""
        counts = chosen.sum(axis=1)
        rows = np.flatnonzero(counts)
        if len(rows) == 0:
            return
        width, counts = counts.max(), counts[rows]
        # Each row's chosen points in grid order, then its last one repeated up to the widest row's count
        row_of, chosen_point = np.nonzero(chosen[rows])
        ends = np.cumsum(counts)
        index = np.repeat(chosen_point[ends - 1][:, None], width, axis=1)
        index[row_of, np.arange(len(chosen_point)) - np.repeat(ends - counts, counts)] = chosen_point
        gathered = np.take_along_axis(queries[rows], index[:, :, None], axis=1)
        values = self.runtime.occupancy(np.ascontiguousarray(z[rows]), gathered, np.ascontiguousarray(points[rows]))
        for row, b in enumerate(rows):
            occupancy[b, index[row, :counts[row]]] = values[row, :counts[row]]

    def _center(self, head: np.ndarray, queries: np.ndarray, occupancy: np.ndarray, inside: np.ndarray) -> np.ndarray:
        if self.config.center == "head" or not inside.any():
            return head
        if self.config.center == "reconstruction":  # the paper: mean of the reconstructed points
            mean: np.ndarray = queries[inside].mean(axis=0)
            return mean
        weights = occupancy[inside]
        weighted_mean: np.ndarray = (queries[inside] * weights[:, None]).sum(axis=0) / weights.sum()
        return weighted_mean

    def resample(self, cloud: np.ndarray) -> np.ndarray:
        """`cloud` [N, 3] resampled to the model's point count, the same way for the same N."""
        resampled: np.ndarray = cloud[self._resample_index(len(cloud))].astype(np.float64)
        return resampled

    def _draw_resample_index(self, count: int) -> np.ndarray:
        rng = np.random.default_rng([self.config.seed, count])
        chosen: np.ndarray = rng.choice(count, size=self.n_points, replace=count < self.n_points)
        chosen.flags.writeable = False  # shared by every observation of `count` points
        return chosen


def _checked_cloud(cloud: np.ndarray, index: int) -> np.ndarray:
    cloud = np.asarray(cloud)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ModelError(f"observation {index}: expected points of shape [N, 3], got {cloud.shape}")
    if not np.all(np.isfinite(cloud)):
        raise ModelError(f"observation {index}: {int((~np.isfinite(cloud)).any(axis=1).sum())} points are NaN or infinite")
    if len(cloud) < MIN_POINTS:
        raise ModelError(f"observation {index}: {len(cloud)} points; at least {MIN_POINTS} are needed to encode a shape")
    return cloud
