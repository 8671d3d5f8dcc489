"""What a real Kinect or RealSense does to a mug beyond Gaussian depth noise (`DepthNoise`).

NDF v2 trains on views with these artifacts, so that its centers and codes hold on real depth
(issue 17, item 4: on the 7-Scenes kitchen the first weights' centers were no steadier than the
visible points' centroid). Each artifact is drawn per view, from the view's own generator:

- quantisation: the disparity step differs between sensors (a Kinect v1 has ~2.9e-3 per metre,
  a finer active-stereo camera ~1e-3): drawn per view, so the model sees the coarse depth
  terraces of a far mug as well as fine ones;
- holes on dark or shiny glaze: structured light returns nothing where the glaze absorbs or
  mirrors the projected pattern: blobs of missing depth over the mug, and on a shiny mug the
  pixels that face the camera (the specular spot);
- missing thin structures: a block-matching sensor cannot resolve anything thinner than its
  matching window, so a handle a few pixels wide vanishes: a morphological opening of the mug's
  valid pixels with a disk of the window's radius;
- flying pixels: at the silhouette, a pixel mixes the mug and the background behind it and
  reports a depth in between: a few points trail behind the mug's outline;
- misregistered colour: when masks come from the colour image and colour is not registered to
  depth (as in 7-Scenes), the mask is shifted by a few pixels against the depth: it loses a strip
  of the mug on one side and takes in what lies beside it on the other.

Of what the mask then holds, only what lies within a few centimetres of the mug's depth is kept,
as a segmentation that clusters the mask's points would.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_opening, zoom

from ndfa.core.errors import SimError
from ndfa.sim.noise import DepthNoise

# The depth window (`SensorArtifacts.mask_depth_window_m`) holds objects up to the widest mug
# (`ndfa.sim.categories.SIZE_RANGES`); a larger object widens it by what it exceeds this by.
WINDOW_OBJECT_SIZE_M = 0.16


@dataclass(frozen=True)
class SensorArtifacts:
    """Per-view artifact settings; probabilities are per view unless said otherwise.

    disparity_step_range_per_m: the DepthNoise disparity step c is drawn uniform in this range.
    edge_dropout: replaces DepthNoise.edge_dropout (part of the edge pixels fly instead).
    dark_probability: chance that the mug's glaze loses depth in blobs.
    dark_hole_fraction_range: share of the mug's pixels inside the blobs, uniform.
    dark_blob_px: size of a blob (the scale of the smooth random field that makes them).
    shiny_probability: chance of a specular spot: pixels whose normal is within
        `shiny_cone_deg` of the ray lose depth.
    thin_probability: chance that thin structures vanish; the opening disk's radius is drawn
        from `thin_radius_px_range` (inclusive; 1 removes structures under 3 px wide).
    flying_probability: chance per surviving silhouette pixel of reporting a depth between the
        mug's and the background's (uniform in between).
    mask_shift_probability: chance that the colour mask is shifted against the depth, by up to
        `mask_shift_px` pixels in each image axis.
    mask_depth_window_m: pixels of the (shifted) mask further than this from the median depth of
        the mug's own pixels are dropped, flying ones included: a segmentation that clusters the
        mask's points would cut them off. An object larger than `WINDOW_OBJECT_SIZE_M` widens it
        by its excess (a 45 cm box seen at a slant spans more than the mug's 12 cm of depth).
    """

    disparity_step_range_per_m: tuple[float, float] = (0.001, 0.003)
    edge_dropout: float = 0.4
    dark_probability: float = 0.3
    dark_hole_fraction_range: tuple[float, float] = (0.05, 0.4)
    dark_blob_px: int = 6
    shiny_probability: float = 0.3
    shiny_cone_deg: float = 12.0
    thin_probability: float = 0.5
    thin_radius_px_range: tuple[int, int] = (1, 2)
    flying_probability: float = 0.3
    mask_shift_probability: float = 0.5
    mask_shift_px: int = 2
    mask_depth_window_m: float = 0.06

    def __post_init__(self) -> None:
        probabilities = (self.edge_dropout, self.dark_probability, self.shiny_probability,
                         self.thin_probability, self.flying_probability, self.mask_shift_probability)
        if not all(0.0 <= p <= 1.0 for p in probabilities):
            raise SimError(f"sensor artifact probabilities must lie in [0, 1]: {self}")
        low, high = self.disparity_step_range_per_m
        hole_low, hole_high = self.dark_hole_fraction_range
        if not (0 <= low <= high and 0 <= hole_low <= hole_high < 1 and self.dark_blob_px >= 1
                and 0 <= self.thin_radius_px_range[0] <= self.thin_radius_px_range[1]
                and self.mask_shift_px >= 0 and self.mask_depth_window_m > 0):
            raise SimError(f"sensor artifact ranges are not valid: {self}")

    def noise_for_view(self, noise: DepthNoise, rng: np.random.Generator) -> DepthNoise:
        """The view's depth noise: its own disparity step, and fewer edge pixels dropped."""
        step = float(rng.uniform(*self.disparity_step_range_per_m))
        return dataclasses.replace(noise, disparity_step_per_m=step, edge_dropout=self.edge_dropout)

    def apply(self, depth: np.ndarray, clean_depth: np.ndarray, mask: np.ndarray, cos_incidence: np.ndarray,
              rng: np.random.Generator, object_size_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The artifacts on one noisy view.

        depth: (H, W) noisy depth (0 = none); clean_depth: the rendered one (for the background
        behind silhouette pixels); mask: (H, W) bool, the mug's pixels; cos_incidence: (H, W)
        |cos| of the angle between each pixel's ray and its normal; object_size_m: the object's
        largest extent (widens the depth window beyond `WINDOW_OBJECT_SIZE_M`).
        Returns the new depth and the mask to take the mug's points from.
        """
        depth = depth.copy()
        # Drawn whether or not each artifact happens, so that one artifact's choice leaves the
        # others' draws alone.
        dark, shiny, thin, shift = rng.random(4)
        hole_fraction = rng.uniform(*self.dark_hole_fraction_range)
        radius = int(rng.integers(self.thin_radius_px_range[0], self.thin_radius_px_range[1] + 1))
        offset = rng.integers(-self.mask_shift_px, self.mask_shift_px + 1, size=2)
        field = _smooth_field(depth.shape, self.dark_blob_px, rng)
        flying = rng.random(depth.shape) < self.flying_probability
        mix = rng.random(depth.shape).astype(np.float32)

        mug = mask & (depth > 0)
        if dark < self.dark_probability and mug.any():
            cut = np.quantile(field[mug], hole_fraction)
            depth[mug & (field < cut)] = 0.0
        if shiny < self.shiny_probability:
            depth[mask & (cos_incidence > np.cos(np.radians(self.shiny_cone_deg)))] = 0.0
        if thin < self.thin_probability and radius > 0:
            valid = mask & (depth > 0)
            kept = binary_opening(valid, structure=_disk(radius))
            depth[valid & ~kept] = 0.0
        own = depth[mask & (depth > 0)]
        depth = self._fly(depth, clean_depth, mask, flying, mix)
        if shift < self.mask_shift_probability and np.any(offset):
            mask = _shifted(mask, offset)
        if own.size:
            window = self.mask_depth_window_m + max(object_size_m - WINDOW_OBJECT_SIZE_M, 0.0)
            mask = mask & (np.abs(depth - np.median(own)) <= window)
        return depth, mask

    def _fly(self, depth: np.ndarray, clean_depth: np.ndarray, mask: np.ndarray, flying: np.ndarray,
             mix: np.ndarray) -> np.ndarray:
        """Silhouette pixels of the mug that still have depth report a depth between the mug's
        and the deepest of their four neighbours' (the background)."""
        behind = np.zeros_like(clean_depth)
        padded = np.pad(clean_depth, 1)
        for dr, dc in ((0, 1), (2, 1), (1, 0), (1, 2)):
            behind = np.maximum(behind, padded[dr:dr + depth.shape[0], dc:dc + depth.shape[1]])
        silhouette = mask & (depth > 0) & (behind - clean_depth > 0.05)
        chosen = silhouette & flying
        depth[chosen] = depth[chosen] + mix[chosen] * (behind[chosen] - clean_depth[chosen])
        return depth


def _shifted(mask: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """The mask moved by `offset` (rows, columns); what moves out of the image is lost."""
    moved = np.zeros_like(mask)
    rows, cols = mask.shape
    dr, dc = int(offset[0]), int(offset[1])
    moved[max(dr, 0):rows + min(dr, 0), max(dc, 0):cols + min(dc, 0)] = \
        mask[max(-dr, 0):rows + min(-dr, 0), max(-dc, 0):cols + min(-dc, 0)]
    return moved


def _smooth_field(shape: tuple[int, ...], blob_px: int, rng: np.random.Generator) -> np.ndarray:
    """A smooth random field (H, W) with features about `blob_px` pixels wide."""
    coarse_shape = (max(shape[0] // blob_px, 1) + 2, max(shape[1] // blob_px, 1) + 2)
    coarse = rng.random(coarse_shape)
    fine = zoom(coarse, (shape[0] / coarse_shape[0] * 1.0001, shape[1] / coarse_shape[1] * 1.0001), order=1)
    return fine[:shape[0], :shape[1]]


def _disk(radius: int) -> np.ndarray:
    r = np.arange(-radius, radius + 1)
    return np.hypot(*np.meshgrid(r, r)) <= radius + 0.5
