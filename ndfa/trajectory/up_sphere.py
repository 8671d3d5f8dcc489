"""The pieces of `ndfa.trajectory.up`'s plane estimate: planar patches of a depth image (normal and
area), and densities and modes of weighted directions on the unit sphere.

Directions are binned on a Fibonacci lattice; a bin's density is the weight of the directions within
a radius of it (a flat kernel, as a sparse bin-to-bin matrix), and a mode is refined by mean shift
over the directions themselves, so the lattice's spacing does not limit the answer.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from ndfa.core.conventions import depth_in_range
from ndfa.core.geometry import backproject


@dataclass(frozen=True)
class PatchConfig:
    """How a depth image is cut into planar patches (see `planar_patches`)."""

    pixel_stride: int = 4
    patch_size: int = 5
    max_patch_rms_m: float = 0.002
    patch_rms_per_m2: float = 0.001
    max_patches_per_frame: int = 3000


def planar_patches(depth: np.ndarray, K: np.ndarray, config: PatchConfig = PatchConfig()) -> tuple[np.ndarray, np.ndarray]:
    """The planar patches of a depth image (metres, 0 or out of range = invalid): their unit normals
    (n, 3) in the camera frame, each oriented towards the camera, and their areas (n,) in m^2; at
    most config.max_patches_per_frame, evenly sampled.

    A patch is config.patch_size^2 samples (every config.pixel_stride-th pixel) with valid depth; its
    normal is the least-variance axis of its points (a plane fit), computed for all patches at once
    from box-filtered moments. It is planar when the RMS distance of its points to the plane is below
    max_patch_rms_m + patch_rms_per_m2 * z^2 (a triangulating camera's noise grows with z^2). Its
    area is the surface its pixels cover: (pixels * z / f)^2 over the cosine between its normal and
    the viewing ray (the cosine clamped at 0.2: grazing patches are the least reliable).
    """
    stride = config.pixel_stride
    z = np.asarray(depth, dtype=np.float64)[::stride, ::stride]
    valid = depth_in_range(z)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    z_valid = np.where(valid, z, 0.0)
    points = backproject(K, rows.ravel() * stride, cols.ravel() * stride, z_valid.ravel()).reshape(*z.shape, 3)

    size = config.patch_size
    empty = np.zeros((0, 3)), np.zeros(0)
    if z.shape[0] < size or z.shape[1] < size:
        return empty
    complete = ndimage.uniform_filter(valid.astype(np.float64), size, mode="constant") > 1.0 - 1e-6
    half = size // 2
    complete[:half], complete[-half:], complete[:, :half], complete[:, -half:] = False, False, False, False
    if not complete.any():
        return empty
    # The moments of each patch, evaluated only at the complete patches' centres.
    mean = np.stack([ndimage.uniform_filter(points[..., i], size, mode="constant")[complete] for i in range(3)], axis=1)
    covariance = np.empty((len(mean), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            second = ndimage.uniform_filter(points[..., i] * points[..., j], size, mode="constant")[complete]
            covariance[:, i, j] = covariance[:, j, i] = second - mean[:, i] * mean[:, j]
    eigenvalues, eigenvectors = np.linalg.eigh(covariance)
    rms = np.sqrt(np.maximum(eigenvalues[:, 0], 0.0))
    planar = rms <= config.max_patch_rms_m + config.patch_rms_per_m2 * mean[:, 2] ** 2
    normals, centres = eigenvectors[planar, :, 0], mean[planar]
    facing = np.einsum("ij,ij->i", normals, centres)
    normals *= -np.sign(facing)[:, None]  # towards the camera
    cosine = np.abs(facing) / np.maximum(np.linalg.norm(centres, axis=1), 1e-9)
    focal = np.sqrt(K[0, 0] * K[1, 1])
    areas = (stride * centres[:, 2] / focal) ** 2 / np.maximum(cosine, 0.2)  # one sample's footprint
    if len(normals) > config.max_patches_per_frame:
        keep = np.linspace(0, len(normals) - 1, config.max_patches_per_frame).astype(int)
        normals, areas = normals[keep], areas[keep]
    return normals, areas


@lru_cache(maxsize=4)
def direction_bins(count: int, radius_deg: float) -> tuple[np.ndarray, sparse.csr_matrix]:
    """Bin centres (count, 3), evenly spread on the unit sphere (a Fibonacci lattice), and the
    sparse (count, count) matrix whose row i marks the bins within radius_deg of bin i."""
    k = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / count)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * k
    centres = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
    chord = 2.0 * np.sin(np.radians(radius_deg) / 2.0)
    pairs = cKDTree(centres).query_pairs(chord, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(count)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(count)])
    return centres, sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(count, count))


def nearest_bin(centres: np.ndarray, directions: np.ndarray) -> np.ndarray:
    return cKDTree(centres).query(directions)[1]


def local_maxima(score: np.ndarray, neighbours: sparse.csr_matrix) -> np.ndarray:
    """Indices of the bins whose positive score is the largest among their neighbours', best first."""
    spread = neighbours.multiply(score[None, :]).tocsr().max(axis=1).toarray().ravel()
    peaks = np.flatnonzero((score > 0.0) & (score >= spread))
    return peaks[np.argsort(-score[peaks])]


def mean_shift(start: np.ndarray, directions: np.ndarray, weights: np.ndarray, radius_deg: float,
               iterations: int = 20) -> np.ndarray:
    """The weighted mean direction of the directions within radius_deg of it, found by iterating from
    `start` (mean shift on the sphere with a flat kernel)."""
    direction = start / np.linalg.norm(start)
    cos_radius = np.cos(np.radians(radius_deg))
    for _ in range(iterations):
        mean = np.where(directions @ direction >= cos_radius, weights, 0.0) @ directions
        norm = np.linalg.norm(mean)
        if norm == 0.0:
            break
        updated = mean / norm
        if updated @ direction > 1.0 - 1e-10:
            return updated
        direction = updated
    return direction
