"""CPU raycast renderer: depth, instance ids, normals and a shaded colour image of a static scene.

One ray per pixel centre is cast in the world frame through Open3D's Embree-backed
`RaycastingScene`, which is built once per scene and reused for every frame. No shadows. An
object has one flat colour, or a `SurfaceTexture` looked up at each ray's hit point (for colour
that odometry can track); the depth and instance images are what the method and the evaluation
use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from ndfa.core.errors import SimError
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import Mesh
from ndfa.sim.texture import SurfaceTexture, TextureAtlas

# Shading: ambient + a fixed "sun" (direction towards the light, world frame, z up: high and to
# one side, so the top, front and sides of a box get different shades) + a headlight at the camera
# (so surfaces facing away from the sun still show their shape). The weights add up to 1, so a
# surface lit head-on by both lights gets exactly its own colour.
_SUN_DIRECTION_WORLD = np.array([0.35, 0.55, 1.0]) / np.linalg.norm([0.35, 0.55, 1.0])
_AMBIENT_WEIGHT = 0.2
_SUN_WEIGHT = 0.45
_HEADLIGHT_WEIGHT = 0.35

_MAX_INSTANCE_ID = np.iinfo(np.uint16).max  # instance images are uint16


@dataclass(frozen=True)
class RenderObject:
    """One mesh to render.

    mesh: triangles in the world frame, metres.
    instance_id: written to the instance image where the object is seen; 0 = not an instance
        (floor, walls, tables), 1..65535 for objects the evaluation tracks.
    color: (r, g, b) albedo in [0, 1].
    texture: an albedo image that replaces `color` where the object is hit, or None.
    """

    mesh: Mesh
    instance_id: int = 0
    color: tuple[float, float, float] = (0.7, 0.7, 0.7)
    texture: SurfaceTexture | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.instance_id <= _MAX_INSTANCE_ID:
            raise SimError(f"instance id {self.instance_id} does not fit the uint16 instance image")
        if len(self.color) != 3 or not all(0.0 <= c <= 1.0 for c in self.color):
            raise SimError(f"colour must be three values in [0, 1], got {self.color}")
        if len(self.mesh.triangles) == 0:
            raise SimError(f"object with instance id {self.instance_id} has an empty mesh")


@dataclass(frozen=True)
class RenderedView:
    """What the camera sees in one frame. H, W are the camera's image height and width.

    depth: (H, W) float32 z-depth in metres (along the optical axis, not the ray length); 0 = no hit.
    instance: (H, W) uint16 instance id of the object hit; 0 = background or no hit.
    rgb: (H, W, 3) uint8 shaded colour; black where nothing is hit.
    normals_camera: (H, W, 3) float32 unit surface normal in the camera frame, turned to face the
        camera (so n . ray < 0); zero where nothing is hit.
    """

    depth: np.ndarray
    instance: np.ndarray
    rgb: np.ndarray
    normals_camera: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(H, W) bool: pixels that see geometry."""
        return self.depth > 0


class SceneRenderer:
    """Renders a fixed set of objects from any camera pose."""

    def __init__(self, objects: list[RenderObject]):
        if not objects:
            raise SimError("nothing to render: the scene has no objects")
        self._scene = o3d.t.geometry.RaycastingScene()
        geometry_ids = [self._scene.add_triangles(obj.mesh.to_open3d_tensor()) for obj in objects]
        # Per-geometry lookup tables, indexed by the geometry id a ray hit, with one extra row at
        # the end for rays that hit nothing (instance 0, black).
        rows = max(geometry_ids) + 2
        self._background_row = rows - 1
        self._instance_of_geometry = np.zeros(rows, dtype=np.uint16)
        self._color_of_geometry = np.zeros((rows, 3), dtype=np.float32)
        for geometry_id, obj in zip(geometry_ids, objects):
            self._instance_of_geometry[geometry_id] = obj.instance_id
            self._color_of_geometry[geometry_id] = obj.color
        # Textured objects: index into one atlas per geometry, -1 for a flat colour (and a miss).
        textured = [(geometry_id, obj.texture) for geometry_id, obj in zip(geometry_ids, objects) if obj.texture is not None]
        self._texture_of_geometry = np.full(rows, -1, dtype=np.intp)
        self._atlas = TextureAtlas([texture for _, texture in textured]) if textured else None
        for index, (geometry_id, _) in enumerate(textured):
            self._texture_of_geometry[geometry_id] = index
        self.triangle_count = sum(len(obj.mesh.triangles) for obj in objects)

    def render(self, camera: PinholeCamera, pose_world_camera: np.ndarray) -> RenderedView:
        """Render the scene seen by `camera` at `pose_world_camera` (4x4 camera-to-world)."""
        pose_world_camera = np.asarray(pose_world_camera, dtype=np.float64)
        if pose_world_camera.shape != (4, 4):
            raise SimError(f"camera pose must be a 4x4 matrix, got shape {pose_world_camera.shape}")
        rotation, origin = pose_world_camera[:3, :3], pose_world_camera[:3, 3]

        # Ray directions keep unit depth (camera z = 1) after rotating them into the world: Open3D
        # measures t_hit in units of the direction's length, so t_hit is the z-depth directly.
        # Written out per coordinate: a matmul into the interleaved (N, 6) array goes through BLAS
        # threads and gets erratic (10x slower) when the CPU is busy.
        rotation32 = rotation.astype(np.float32)
        rays_camera = camera.pixel_rays()
        x, y = rays_camera[..., 0].ravel(), rays_camera[..., 1].ravel()
        rays = np.empty((camera.height * camera.width, 6), dtype=np.float32)
        for axis in range(3):
            rays[:, axis] = origin[axis]
            rays[:, 3 + axis] = rotation32[axis, 0] * x + rotation32[axis, 1] * y + rotation32[axis, 2]
        rays = rays.reshape(camera.height, camera.width, 6)
        hits = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays))

        depth = hits["t_hit"].numpy()  # (H, W) float32, inf on a miss
        hit = np.isfinite(depth)
        depth[~hit] = 0.0
        row = hits["geometry_ids"].numpy()  # (H, W) uint32, INVALID_ID on a miss
        row[~hit] = self._background_row
        instance = np.take(self._instance_of_geometry, row)

        # Embree reports the geometric normal of the triangle hit (world frame, unit length, zero
        # on a miss). Back faces are hit too (open meshes, the inside of a mug), so turn every
        # normal towards the camera; the noise model and the shading both want the facing side.
        normals_world = hits["primitive_normals"].numpy()
        normals_camera = normals_world @ rotation32
        cos_ray = camera.ray_cosines(normals_camera)
        normals_camera *= np.where(cos_ray > 0, np.float32(-1.0), np.float32(1.0))[..., None]

        # Lambertian shading; the headlight's cosine is the one just computed.
        sun_camera = (rotation.T @ _SUN_DIRECTION_WORLD).astype(np.float32)
        sun = np.maximum(normals_camera @ sun_camera, 0.0)
        brightness = _AMBIENT_WEIGHT + _SUN_WEIGHT * sun + _HEADLIGHT_WEIGHT * np.abs(cos_ray)
        rgb = np.take(self._color_of_geometry, row, axis=0)  # (H, W, 3) albedo, 0 on a miss
        if self._atlas is not None:
            texture_index = np.take(self._texture_of_geometry, row).ravel()
            pixels = np.flatnonzero(texture_index >= 0)
            # The hit point: the ray's origin plus its unit-depth direction times the z-depth.
            points = rays.reshape(-1, 6)[pixels, 3:] * depth.ravel()[pixels, None] + origin.astype(np.float32)
            rgb.reshape(-1, 3)[pixels] = self._atlas.albedo(texture_index[pixels], points,
                                                            normals_world.reshape(-1, 3)[pixels])
        rgb *= (255.0 * brightness)[..., None]
        # The weights add up to 1 and colours are <= 1, so rgb <= 255 up to rounding: +0.5 rounds.
        rgb = np.minimum(rgb + 0.5, 255.0).astype(np.uint8)
        return RenderedView(depth, instance, rgb, normals_camera)

