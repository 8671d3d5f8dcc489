"""A colour camera that is not the depth camera: colour images not registered to the depth.

A Kinect v1 (the 7-Scenes recordings) has its colour camera (about 525 px focal length) 2.5 cm
beside its depth camera (585 px): the same corner sits up to 30 px apart in the two images. Methods
that pair a pixel's colour with its depth (RGB-D odometry's intensity term, features lifted to 3D
by their depth) need the colour carried onto the depth pixels first (`register_to_depth`).

A recording says so in its meta (`META_KEY`, written by `ndfa ingest tum --color-intrinsics`).

Pure: images and numbers in, images out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

META_KEY = "color_camera"


@dataclass(frozen=True)
class ColorCamera:
    """The colour camera's pinhole intrinsics (pixels) and its offset from the depth camera along the
    depth camera's x axis (metres; the two are taken as parallel, as on a Kinect)."""

    fx: float
    fy: float
    cx: float
    cy: float
    offset_x_m: float = 0.0

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy, self.offset_x_m)
        if not all(math.isfinite(value) for value in values) or min(self.fx, self.fy) <= 0:
            raise ValueError(f"a colour camera needs finite intrinsics and positive focal lengths, got {values}")

    @classmethod
    def parse(cls, text: str) -> ColorCamera:
        """From 'fx,fy,cx,cy' or 'fx,fy,cx,cy,dx' (the CLI's form); ValueError naming the problem."""
        try:
            values = [float(value) for value in text.split(",")]
        except ValueError:
            values = []
        if len(values) not in (4, 5):
            raise ValueError(f"must be fx,fy,cx,cy or fx,fy,cx,cy,dx (numbers), got {text!r}")
        return cls(*values)

    def to_meta(self) -> dict[str, float]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "offset_x_m": self.offset_x_m}

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> ColorCamera | None:
        """The colour camera a recording's meta names (None: its colour is registered to its depth)."""
        value = meta.get(META_KEY)
        if value is None:
            return None
        return cls(float(value["fx"]), float(value["fy"]), float(value["cx"]), float(value["cy"]),
                   float(value.get("offset_x_m", 0.0)))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def register_to_depth(self, rgb: np.ndarray, depth: np.ndarray, depth_K: np.ndarray) -> np.ndarray:
        """The colour each depth pixel's point has in `rgb` (H, W, 3), sampled bilinearly: an image
        registered to `depth` (H, W, metres, 0 or NaN invalid). A pixel without depth takes the
        colour along its ray at the frame's median depth (the offset's parallax is then a guess;
        its depth is unused anyway)."""
        import cv2

        valid = np.isfinite(depth) & (depth > 0)
        fill = float(np.median(depth[valid])) if valid.any() else 1.0
        z = np.where(valid, depth, fill).astype(np.float64)
        rows, cols = np.indices(depth.shape, dtype=np.float64)
        x = (cols - depth_K[0, 2]) / depth_K[0, 0] * z + self.offset_x_m
        y = (rows - depth_K[1, 2]) / depth_K[1, 1] * z
        map_x = (self.cx + self.fx * x / z).astype(np.float32)
        map_y = (self.cy + self.fy * y / z).astype(np.float32)
        return np.asarray(cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
