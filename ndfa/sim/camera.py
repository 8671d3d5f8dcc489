"""The pinhole camera model: intrinsics, pixel rays, projection and back-projection.

Frames and conventions follow ndfa.core.geometry: the OpenCV camera frame (x right, y down, z forward
along the optical axis), metres. Pixel (row v, column u) has its centre at image coordinates
(u, v); the top-left pixel's centre is (0, 0), so a centred principal point is ((W-1)/2, (H-1)/2).
Depth images hold z-depth (the point's z in the camera frame), not the length of the ray.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import project

# 60 degrees of horizontal field of view over 640 pixels: fx = 320 / tan(30 deg) ~ 554.26 px.
_DEFAULT_FOCAL_PX = 320.0 / math.tan(math.radians(30.0))


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics, no lens distortion (a synthetic sensor has none).

    The defaults are a 640x480 sensor with a 60 deg horizontal (about 47 deg vertical) field of
    view and square pixels: close to the depth camera of a Kinect v1 / Asus Xtion (58 x 45 deg) and
    a little narrower than a RealSense D415 (65 deg), i.e. an ordinary consumer RGB-D camera.

    width, height: image size in pixels.
    fx, fy: focal lengths in pixels.
    cx, cy: principal point in pixels (image coordinates of the optical axis).
    """

    width: int = 640
    height: int = 480
    fx: float = _DEFAULT_FOCAL_PX
    fy: float = _DEFAULT_FOCAL_PX
    cx: float = 319.5
    cy: float = 239.5

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise SimError(f"camera image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise SimError(f"camera focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @staticmethod
    def from_fov(width: int, height: int, hfov_deg: float) -> "PinholeCamera":
        """Camera with square pixels, a centred principal point and `hfov_deg` degrees of
        horizontal field of view (edge to edge of the image)."""
        if not 0.0 < hfov_deg < 180.0:
            raise SimError(f"horizontal field of view must be in (0, 180) degrees, got {hfov_deg}")
        focal = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return PinholeCamera(width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0)

    def scaled(self, factor: float) -> "PinholeCamera":
        """The same camera at `factor` times the resolution (e.g. 0.5 for 320x240), with the same
        field of view. Pixel centres scale about the image corner (-0.5, -0.5), hence the +-0.5."""
        width, height = round(self.width * factor), round(self.height * factor)
        if width < 1 or height < 1:
            raise SimError(f"scaling {self.width}x{self.height} by {factor} leaves no pixels")
        return PinholeCamera(
            width,
            height,
            self.fx * factor,
            self.fy * factor,
            (self.cx + 0.5) * factor - 0.5,
            (self.cy + 0.5) * factor - 0.5,
        )

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width): the shape of this camera's images."""
        return self.height, self.width

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) float32 ray direction through each pixel centre, in the camera frame, scaled
        to unit depth (z = 1): the point seen at pixel (v, u) with depth d is d * rays[v, u].
        float32 like the depth images it multiplies; read-only, computed once per camera."""
        return _unit_depth_rays(self)

    def pixel_directions(self) -> np.ndarray:
        """(H, W, 3) float32 unit-length ray direction through each pixel centre, camera frame
        (for angles between rays and surfaces). Read-only, computed once per camera."""
        return _unit_length_rays(self)

    def ray_cosines(self, vectors_camera: np.ndarray) -> np.ndarray:
        """(H, W) cosine of the angle between each pixel's ray and a unit vector per pixel
        (H, W, 3) in the camera frame, e.g. a surface normal: -1 for a surface facing the camera
        head-on, 0 when the ray grazes it."""
        rays = self.pixel_directions()
        # Written out per component: several times faster than np.sum(a * b, axis=-1).
        return (vectors_camera[..., 0] * rays[..., 0] + vectors_camera[..., 1] * rays[..., 1]
                + vectors_camera[..., 2] * rays[..., 2])

    def backproject(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lift a depth image to a point cloud in the camera frame.

        depth: (H, W) z-depth in metres; 0 (or NaN) marks an invalid pixel.
        Returns `points` (N, 3) float64 in the camera frame, one per valid pixel in row-major order,
        and `pixels` (N, 2) int64 (row, column) of each point, so that
        `image[pixels[:, 0], pixels[:, 1]]` picks the matching values of any other image.
        """
        depth = np.asarray(depth)
        if depth.shape != self.shape:
            raise SimError(f"depth image has shape {depth.shape}, the camera's is {self.shape}")
        valid = np.isfinite(depth) & (depth > 0)
        rows, cols = np.nonzero(valid)
        points = self.pixel_rays()[rows, cols].astype(np.float64) * depth[rows, cols, None]
        return points, np.stack([rows, cols], axis=1)

    def project(self, points_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project points (N, 3) in the camera frame to image coordinates.

        Returns `uv` (N, 2) float64 image coordinates (column u, row v; pixel centres at integers)
        and `z` (N,) their depth. Points with z <= 0 are behind the camera and their uv is
        meaningless, so callers keep z > 0; a point is inside the image when -0.5 <= u < W - 0.5
        and -0.5 <= v < H - 0.5, and its pixel is (round(v), round(u)).
        """
        points_camera = np.asarray(points_camera, dtype=np.float64)
        return project(self.K, points_camera), points_camera[:, 2]


@functools.lru_cache(maxsize=8)
def _unit_depth_rays(camera: PinholeCamera) -> np.ndarray:
    # Cached because every rendered frame and every back-projection needs the same rays; a frozen
    # dataclass is hashable, so equal cameras share one array.
    u = (np.arange(camera.width) - camera.cx) / camera.fx
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    rays = np.empty((camera.height, camera.width, 3), dtype=np.float32)
    rays[..., 0] = u[None, :]
    rays[..., 1] = v[:, None]
    rays[..., 2] = 1.0
    rays.setflags(write=False)
    return rays


@functools.lru_cache(maxsize=8)
def _unit_length_rays(camera: PinholeCamera) -> np.ndarray:
    rays = _unit_depth_rays(camera)
    directions = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    directions.setflags(write=False)
    return directions
