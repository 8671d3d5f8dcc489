"""Depth sensor noise: what turns a perfect rendered depth image into a consumer RGB-D camera's.

The model, applied per pixel in this order (vectorised, deterministic given the rng):
1. Gaussian noise on the z-depth with sigma(z) = a + b * z^2: triangulating sensors (structured
   light, active stereo) measure disparity, whose error maps to a depth error growing with z^2.
2. Quantisation: disparity comes in sub-pixel steps, so depth comes in steps of c * z^2; and the
   recording stores whole millimetres, so never finer than 1 mm.
3. Dropout (depth 0) at grazing incidence, next to depth discontinuities (occlusion shadows and
   mixed pixels), and at random; and outside the sensor's working range.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.camera import PinholeCamera


@dataclass(frozen=True)
class DepthNoise:
    """Depth noise settings. Defaults are typical of a short-range structured-light / active-stereo
    RGB-D camera (Kinect v1, RealSense D400 class): about 2.5 mm of noise at 1 m, 15 mm at 3 m.

    enabled: False returns depth unchanged (noiseless renders for tests and debugging).
    sigma_base_m: a in sigma(z) = a + b z^2, metres.
    sigma_quadratic_per_m: b in sigma(z) = a + b z^2, 1/metre (1.5e-3 = 1.5 mm at 1 m).
    disparity_step_per_m: c, the depth step is c z^2 metres; c = (sub-pixel disparity step) /
        (focal length in px * baseline in m). A Kinect v1 (1/8 px, 580 px, 75 mm) has 2.9e-3;
        the default 1e-3 (1 mm at 1 m, 9 mm at 3 m) is a finer modern active-stereo camera.
        0 turns disparity quantisation off.
    min_step_m: depth is always rounded to this (1 mm: the recording's 16-bit millimetres).
    grazing_start_deg: angle between the ray and the surface normal at which dropout starts.
    grazing_full_deg: angle beyond which every pixel drops out; the dropout probability ramps
        linearly from 0 to 1 between the two angles.
    edge_jump_m: a depth difference between neighbouring pixels above this is a discontinuity.
    edge_width_px: pixels within this many pixels (of a jump, on both sides) may drop out.
    edge_dropout: probability that such an edge pixel drops out.
    random_dropout: probability that any pixel drops out.
    min_range_m, max_range_m: measured depths outside [min, max] drop out.
    """

    enabled: bool = True
    sigma_base_m: float = 0.001
    sigma_quadratic_per_m: float = 0.0015
    disparity_step_per_m: float = 0.001
    min_step_m: float = 0.001
    grazing_start_deg: float = 75.0
    grazing_full_deg: float = 88.0
    edge_jump_m: float = 0.05
    edge_width_px: int = 1
    edge_dropout: float = 0.8
    random_dropout: float = 0.002
    min_range_m: float = 0.2
    max_range_m: float = 6.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.grazing_start_deg < self.grazing_full_deg <= 90.0:
            raise SimError("grazing dropout needs 0 <= grazing_start_deg < grazing_full_deg <= 90")
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise SimError(f"depth range [{self.min_range_m}, {self.max_range_m}] m is empty")
        for name in ("edge_dropout", "random_dropout"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise SimError(f"{name} is a probability, got {getattr(self, name)}")
        if min(self.sigma_base_m, self.sigma_quadratic_per_m, self.disparity_step_per_m, self.min_step_m) < 0:
            raise SimError("noise magnitudes and quantisation steps must not be negative")
        if self.edge_width_px < 0:
            raise SimError(f"edge_width_px must be >= 0, got {self.edge_width_px}")

    @staticmethod
    def off() -> "DepthNoise":
        """A model that leaves depth exactly as rendered."""
        return DepthNoise(enabled=False)

    def scaled(self, factor: float) -> "DepthNoise":
        """The same sensor with `factor` times the Gaussian noise (a knob for sweeps)."""
        return dataclasses.replace(self, sigma_base_m=self.sigma_base_m * factor,
                                   sigma_quadratic_per_m=self.sigma_quadratic_per_m * factor)

    def sigma(self, depth: np.ndarray) -> np.ndarray:
        """Standard deviation (m) of the Gaussian noise at z-depth `depth` (m)."""
        return self.sigma_base_m + self.sigma_quadratic_per_m * np.square(depth)

    def apply(self, depth: np.ndarray, normals_camera: np.ndarray, rng: np.random.Generator,
              camera: PinholeCamera) -> np.ndarray:
        """A noisy copy of a rendered depth image.

        depth: (H, W) float32 z-depth in metres, 0 = no measurement.
        normals_camera: (H, W, 3) unit surface normals in the camera frame (RenderedView's).
        rng: the only source of randomness: the same generator state gives the same output.
        camera: the camera that rendered `depth` (for the viewing ray of each pixel).
        Returns (H, W) float32 metres, 0 where the sensor reports nothing.
        """
        depth = np.asarray(depth, dtype=np.float32)
        if not self.enabled:
            return depth.copy()
        if depth.shape != camera.shape or normals_camera.shape != (*camera.shape, 3):
            raise SimError(f"depth {depth.shape} and normals {normals_camera.shape} do not match "
                           f"the camera's {camera.shape} image")
        valid = depth > 0
        # Draw full images, not just valid pixels, so the rng advances the same way whatever the
        # scene looks like: one normal draw for the noise, one uniform draw for all dropouts.
        gaussian = rng.standard_normal(depth.shape, dtype=np.float32)
        uniform = rng.random(depth.shape, dtype=np.float32)

        noisy = depth + self.sigma(depth) * gaussian
        noisy = self._quantise(noisy)

        # The dropout causes are independent: a pixel survives if it survives each of them.
        keep = (1.0 - self._grazing_probability(normals_camera, camera)) \
            * (1.0 - self.edge_dropout * self._near_edge(depth)) \
            * (1.0 - self.random_dropout)
        in_range = (noisy >= self.min_range_m) & (noisy <= self.max_range_m)
        return np.where(valid & in_range & (uniform < keep), noisy, 0.0).astype(np.float32)

    def _quantise(self, depth: np.ndarray) -> np.ndarray:
        # Round in disparity (~ 1/z) units of one sub-pixel step: z = 1 / (c * k), k integer. Only
        # where the disparity step is coarser than min_step_m, which also keeps 1/z finite.
        if self.disparity_step_per_m > 0:
            c = self.disparity_step_per_m
            coarse = c * np.square(depth) > self.min_step_m
            with np.errstate(divide="ignore"):
                levels = np.rint(1.0 / (c * depth))
                depth = np.where(coarse & (levels > 0), 1.0 / (c * levels), depth)
        if self.min_step_m > 0:
            depth = np.rint(depth / self.min_step_m) * self.min_step_m
        return depth

    def _grazing_probability(self, normals_camera: np.ndarray, camera: PinholeCamera) -> np.ndarray:
        """(H, W) dropout probability from the angle between each pixel's ray and its normal."""
        cos_incidence = np.abs(camera.ray_cosines(normals_camera))
        angle_deg = np.degrees(np.arccos(np.minimum(cos_incidence, 1.0)))
        ramp = (angle_deg - self.grazing_start_deg) / (self.grazing_full_deg - self.grazing_start_deg)
        return np.clip(ramp, 0.0, 1.0)

    def _near_edge(self, depth: np.ndarray) -> np.ndarray:
        """(H, W) bool: pixels within edge_width_px of a depth jump larger than edge_jump_m.
        A pixel next to one without depth (no hit) counts as next to a jump."""
        jump_right = np.abs(np.diff(depth, axis=1)) > self.edge_jump_m   # (H, W-1)
        jump_down = np.abs(np.diff(depth, axis=0)) > self.edge_jump_m    # (H-1, W)
        edge = np.zeros(depth.shape, dtype=bool)
        if self.edge_width_px == 0:
            return edge
        # Mark both pixels of every jump, then widen the band one pixel per extra step.
        edge[:, :-1] |= jump_right
        edge[:, 1:] |= jump_right
        edge[:-1, :] |= jump_down
        edge[1:, :] |= jump_down
        for _ in range(self.edge_width_px - 1):
            grown = edge.copy()
            grown[:, :-1] |= edge[:, 1:]
            grown[:, 1:] |= edge[:, :-1]
            grown[:-1, :] |= edge[1:, :]
            grown[1:, :] |= edge[:-1, :]
            edge = grown
        return edge
