"""Planting changes into a real RGB-D frame: an object taken out, a mesh put in (`ndfa plant`).

All geometry is in a z-up world (the recording's world levelled, as `ndfa detect` levels it):
`pose_world_camera` below is the camera in that world.

- **Removing** an object: its region is a vertical cylinder standing on a support plane (the
  plane's normal, its foot, a radius and a height). The object's pixels are those whose point lies
  in the cylinder above the plane, plus the pixels next to them that show something above the
  plane near it or nothing at all (the sensor's mixed pixels and shadows at the object's edges).
  Their depth becomes the plane's along each ray, with the sensor's noise
  (`ndfa.sim.noise.DepthNoise`); their colour the nearest visible plane pixels' around the hole,
  smoothed (a simple fill: the detector reads depth, a viewer the colour).
- **Adding** a mesh: ray cast per frame with the frame's intrinsics through the simulator's
  renderer (`ndfa.sim.render.SceneRenderer`: Open3D's `RaycastingScene`, shaded colour), the
  sensor's noise applied, and z-tested against the real depth: a real surface nearer than the mesh
  hides it, and where the real sensor saw nothing the mesh shows.

Pure numpy / scipy / Open3D; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ndfa.sim.camera import PinholeCamera
from ndfa.sim.noise import DepthNoise
from ndfa.sim.render import RenderObject, SceneRenderer

# Points this far above the support plane belong to what stands on it; below, to the plane (its
# noise is a few millimetres at the distances a table is seen from).
ABOVE_PLANE_M = 0.008
# Pixels this far around an object's own pixels may hold its mixed pixels and the sensor's shadows.
EDGE_PX = 4
# ... when their point (or, without depth, the plane behind them) lies within this of the cylinder.
EDGE_REACH_M = 0.05
# The colour hole reaches this many pixels beyond the depth's.
COLOR_MARGIN_PX = 4
# The colour of a hole is taken from plane pixels within this many pixels around it.
RING_PX = 12
# The colour fill is smoothed over about this many pixels, so it shows no streaks.
SMOOTH_PX = 3.0


@dataclass(frozen=True)
class SupportPlane:
    """A plane points p with normal . p = offset lie on; `normal` is unit length and points up."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed height of `points` (..., 3) above the plane, metres."""
        return points @ self.normal - self.offset

    def foot(self, xy: np.ndarray) -> np.ndarray:
        """The point of the plane above or below horizontal position `xy` (2,)."""
        x, y = float(xy[0]), float(xy[1])
        n = self.normal
        return np.array([x, y, (self.offset - n[0] * x - n[1] * y) / n[2]])


@dataclass(frozen=True)
class Cylinder:
    """The region an object takes up: `radius` around the plane normal through `foot` (a point of
    the plane), up to `height` above the plane."""

    foot: np.ndarray
    radius: float
    height: float
    plane: SupportPlane

    def radial(self, points: np.ndarray) -> np.ndarray:
        """Distance of `points` (..., 3) from the cylinder's axis."""
        offset = points - self.foot
        along = offset @ self.plane.normal
        return np.linalg.norm(offset - along[..., None] * self.plane.normal, axis=-1)

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether `points` (..., 3) lie in the cylinder (widened by `margin`) and above the plane."""
        height = self.plane.height(points)
        return (height > ABOVE_PLANE_M) & (height <= self.height + margin) & (self.radial(points) <= self.radius + margin)


@dataclass(frozen=True, eq=False)
class ColorGrid:
    """The colour camera of a recording whose colour is not registered to its depth (7-Scenes: a
    Kinect's colour camera, 525 px, 2.5 cm beside its depth camera, 585 px): its intrinsics and
    its offset from the depth camera along the depth camera's x axis. A depth pixel's point (its
    depth known) is seen by the colour camera at `splat`'s pixel."""

    depth_K: np.ndarray
    color_K: np.ndarray
    offset_x_m: float = 0.0

    def splat(self, mask: np.ndarray, depth: np.ndarray, values: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
        """The depth pixels of `mask` (with `depth` > 0) moved to where the colour camera sees
        their points: the colour image's mask, and `values` (H, W, ...) carried along (nearest
        point wins where several land on one pixel)."""
        rows, cols = np.nonzero(mask & (depth > 0))
        z = depth[rows, cols].astype(np.float64)
        order = np.argsort(-z)  # far first: the nearest is written last
        rows, cols, z = rows[order], cols[order], z[order]
        x = (cols - self.depth_K[0, 2]) / self.depth_K[0, 0] * z + self.offset_x_m
        y = (rows - self.depth_K[1, 2]) / self.depth_K[1, 1] * z
        u = np.rint(self.color_K[0, 2] + self.color_K[0, 0] * x / z).astype(int)
        v = np.rint(self.color_K[1, 2] + self.color_K[1, 1] * y / z).astype(int)
        inside = (u >= 0) & (u < mask.shape[1]) & (v >= 0) & (v < mask.shape[0])
        out = np.zeros(mask.shape, dtype=bool)
        out[v[inside], u[inside]] = True
        if values is None:
            return out, None
        carried = np.zeros_like(values)
        carried[v[inside], u[inside]] = values[rows[inside], cols[inside]]
        return out, carried


def camera_of(K: np.ndarray, image_size: tuple[int, int]) -> PinholeCamera:
    """The pinhole camera of intrinsics `K` for images of (H, W) = `image_size`."""
    return PinholeCamera(width=image_size[1], height=image_size[0], fx=float(K[0, 0]), fy=float(K[1, 1]),
                         cx=float(K[0, 2]), cy=float(K[1, 2]))


def world_points(depth: np.ndarray, camera: PinholeCamera, pose_world_camera: np.ndarray) -> np.ndarray:
    """(H, W, 3) world point of every pixel (meaningless where depth is 0)."""
    points_camera = camera.pixel_rays() * depth[..., None]
    return points_camera @ pose_world_camera[:3, :3].T + pose_world_camera[:3, 3]


def plane_depth(plane: SupportPlane, camera: PinholeCamera, pose_world_camera: np.ndarray) -> np.ndarray:
    """(H, W) z-depth at which each pixel's ray meets `plane`; 0 where it never does (parallel, or
    the plane lies behind the camera)."""
    directions = camera.pixel_rays() @ pose_world_camera[:3, :3].T  # unit depth: t is the z-depth
    towards = directions @ plane.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (plane.offset - pose_world_camera[:3, 3] @ plane.normal) / towards
    return np.where(np.isfinite(t) & (t > 0), t, 0.0).astype(np.float32)


def object_pixels(depth: np.ndarray, camera: PinholeCamera, pose_world_camera: np.ndarray,
                  region: Cylinder) -> np.ndarray:
    """(H, W) bool: the pixels that show what stands in `region` (its surface, its mixed edge pixels
    and the sensor's shadows beside it; see the module docstring)."""
    valid = depth > 0
    points = world_points(depth, camera, pose_world_camera)
    inside = valid & region.contains(points)
    if not inside.any():
        return inside
    near = ndimage.binary_dilation(inside, iterations=EDGE_PX) & ~inside
    # Near pixels with depth: points above the plane close to the cylinder (mixed pixels).
    edge = near & valid & region.contains(points, margin=EDGE_REACH_M)
    # Near pixels without depth: where the plane behind them lies close to the cylinder (shadows).
    behind = plane_depth(region.plane, camera, pose_world_camera)
    foot_points = world_points(behind, camera, pose_world_camera)
    shadow = near & ~valid & (behind > 0) & (region.radial(foot_points) <= region.radius + EDGE_REACH_M)
    return inside | edge | shadow


def remove_object(rgb: np.ndarray | None, depth: np.ndarray, camera: PinholeCamera, pose_world_camera: np.ndarray,
                  region: Cylinder, noise: DepthNoise, rng: np.random.Generator, grid: ColorGrid | None = None
                  ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """The frame's colour and depth with what stands in `region` replaced by the plane behind it,
    and the (H, W) bool mask of the depth pixels replaced. `grid`: the colour camera when the
    colour is not registered to the depth (None: it is)."""
    hole = object_pixels(depth, camera, pose_world_camera, region)
    if not hole.any():
        return rgb, depth, hole
    behind = plane_depth(region.plane, camera, pose_world_camera)
    filled = np.where(hole, behind, depth).astype(np.float32)
    normal_camera = (pose_world_camera[:3, :3].T @ region.plane.normal).astype(np.float32)
    normals = np.broadcast_to(normal_camera, (*depth.shape, 3))
    # The noise model over the whole composed image: its dropout at depth edges sees the real
    # neighbours of the hole; only the hole's pixels are taken from it.
    noisy = noise.apply(filled, normals, rng, camera)
    out_depth = np.where(hole, noisy, depth).astype(np.float32)
    if rgb is None:
        return None, out_depth, hole
    on_plane = (depth > 0) & (np.abs(region.plane.height(world_points(depth, camera, pose_world_camera))) < 0.015)
    color_hole = hole
    if grid is not None:  # where the colour camera sees the hole's points (the object's; the plane's without depth)
        color_hole, _ = grid.splat(hole, np.where(depth > 0, depth, behind))
        on_plane, _ = grid.splat(on_plane, depth)
    # The colour's edge bleeds past the depth's (the two sensors' resolution, and the registration's
    # error): the colour hole reaches a few pixels further.
    out_rgb = _fill_colour(rgb, ndimage.binary_dilation(color_hole, iterations=COLOR_MARGIN_PX), on_plane)
    return out_rgb, out_depth, hole


def _fill_colour(rgb: np.ndarray, hole: np.ndarray, on_plane: np.ndarray) -> np.ndarray:
    """`rgb` with the hole's pixels coloured from the nearest plane pixels around it, smoothed."""
    ring = ndimage.binary_dilation(hole, iterations=RING_PX) & ~hole
    sources = ring & on_plane if (ring & on_plane).sum() >= 10 else ring
    out = rgb.copy()
    if not sources.any():
        return out
    # Every pixel takes the colour of its nearest source pixel, then the fill is blurred.
    _, (rows, cols) = ndimage.distance_transform_edt(~sources, return_indices=True)
    nearest = rgb[rows, cols].astype(np.float32)
    smooth = np.stack([ndimage.gaussian_filter(nearest[..., c], SMOOTH_PX) for c in range(3)], axis=-1)
    out[hole] = np.clip(smooth[hole] + 0.5, 0, 255).astype(np.uint8)
    return out


class MeshInserter:
    """Puts a fixed set of world-frame meshes into real frames (see the module docstring)."""

    def __init__(self, meshes: list[RenderObject], noise: DepthNoise):
        self._renderer = SceneRenderer(meshes) if meshes else None
        self._noise = noise

    def insert(self, rgb: np.ndarray | None, depth: np.ndarray, camera: PinholeCamera, pose_world_camera: np.ndarray,
               rng: np.random.Generator, grid: ColorGrid | None = None
               ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """The frame with the meshes put in, and the (H, W) uint16 instance id of the mesh each
        depth pixel now shows (0: the real scene). `grid`: the colour camera when the colour is
        not registered to the depth (None: it is)."""
        shown = np.zeros(depth.shape, dtype=np.uint16)
        if self._renderer is None:
            return rgb, depth, shown
        view = self._renderer.render(camera, pose_world_camera)
        if not view.hit.any():
            return rgb, depth, shown
        noisy = self._noise.apply(view.depth, view.normals_camera, rng, camera)
        # The z-test on the noiseless depth: a mesh resting on a real table must not flicker under it.
        front = view.hit & ((depth <= 0) | (view.depth < depth))
        out_depth = np.where(front, noisy, depth).astype(np.float32)
        shown[front] = view.instance[front]
        out_rgb = None
        if rgb is not None:
            out_rgb = rgb.copy()
            front_color, shaded = (front, view.rgb) if grid is None else grid.splat(front, view.depth, view.rgb)
            out_rgb[front_color] = shaded[front_color]
        return out_rgb, out_depth, shown
