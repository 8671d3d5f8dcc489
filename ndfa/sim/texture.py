"""Procedural colour textures for the static room: plaster walls with posters, a tiled or planked
floor, wood-grain table tops.

Why: photometric RGB-D odometry and any colour feature need texture to lock onto, as in a real
room; the untextured scene is flat-shaded and gives them nothing but the shading edges.

A `SurfaceTexture` is an albedo image laid on a mesh by planar projection in the texture's own
frame: each hit point is projected along the axis its surface normal points most along (a face
whose normal is mostly z gets the image's (x, y), one whose normal is mostly x gets (y, z), mostly
y gets (x, z)), so the big face of a wall slab or a table top shows the image undistorted, and
the thin sides show a stretched edge of it. Outside the image it repeats. Every image is drawn
from a seeded generator and covers its whole surface at about 1 cm per texel, so no pattern
repeats across a wall or the floor (a repeating pattern would give odometry false matches).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import make_pose
from ndfa.sim.scene import Room, Table

TEXEL_M = 0.01  # texture resolution: a texel covers about 3 pixels of a 640x480 view at 1 m


@dataclass(frozen=True, eq=False)
class SurfaceTexture:
    """An albedo image on a surface.

    image: (H, W, 3) float32 albedo in [0, 1]; texel (row j, column i) covers u in
        [i, i + 1) * texel_m and v in [j, j + 1) * texel_m.
    texel_m: edge length of a texel in metres.
    pose_world_texture: (4, 4) the texture frame in the world: the image's origin is its origin,
        and (u, v) are its (x, y), (y, z) or (x, z) coordinates depending on the face's normal.
        Its z must be the world's z (a turn about z and a shift): the room and the tables stand
        upright, and the lookup is cheaper for it.
    """

    image: np.ndarray
    texel_m: float = TEXEL_M
    pose_world_texture: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        if self.image.ndim != 3 or self.image.shape[2] != 3 or min(self.image.shape[:2]) < 2:
            raise SimError(f"a texture image must be (H, W, 3) with H, W >= 2, got {self.image.shape}")
        if not self.texel_m > 0:
            raise SimError(f"texel size must be positive, got {self.texel_m}")
        if not np.allclose(self.pose_world_texture[:3, 2], [0.0, 0.0, 1.0], atol=1e-9):
            raise SimError("a texture frame must keep the world's z axis (a turn about z and a shift)")

    def albedo(self, points_world: np.ndarray, normals_world: np.ndarray) -> np.ndarray:
        """(N, 3) float32 albedo at world points (N, 3) on faces with world normals (N, 3)."""
        return TextureAtlas([self]).albedo(np.zeros(len(points_world), dtype=np.intp), points_world, normals_world)


class TextureAtlas:
    """Many textures sampled in one pass: the renderer looks up every textured pixel of a frame
    at once, whatever texture it shows (a pass per texture costs more than the lookups).

    The images are packed one after the other into one (texels, 3) array, each with a copy of its
    first column appended on the right and of its first row on top, so that the four texels of a
    bilinear lookup are always at k, k + 1, k + stride and k + stride + 1, without wrapping.
    Per texture, its offset, stride, height, texel size and frame are small tables gathered per
    pixel."""

    def __init__(self, textures: list[SurfaceTexture]):
        if not textures:
            raise SimError("a texture atlas needs at least one texture")
        padded = []
        for texture in textures:
            image = np.concatenate([texture.image, texture.image[:, :1]], axis=1)
            padded.append(np.concatenate([image, image[:1]], axis=0).astype(np.float32))
        self._texels = np.concatenate([image.reshape(-1, 3) for image in padded])
        self._offset = np.cumsum([0] + [image.shape[0] * image.shape[1] for image in padded[:-1]]).astype(np.intp)
        self._stride = np.array([image.shape[1] for image in padded], dtype=np.intp)
        self._height = np.array([t.image.shape[0] for t in textures], dtype=np.intp)
        self._per_texel = np.array([1.0 / t.texel_m for t in textures], dtype=np.float32)
        self._cos = np.array([t.pose_world_texture[0, 0] for t in textures], dtype=np.float32)
        self._sin = np.array([t.pose_world_texture[1, 0] for t in textures], dtype=np.float32)
        self._origin = np.array([t.pose_world_texture[:3, 3] for t in textures], dtype=np.float32).T  # (3, T)

    def albedo(self, texture_index: np.ndarray, points_world: np.ndarray, normals_world: np.ndarray) -> np.ndarray:
        """(N, 3) float32 albedo at world points (N, 3) with face normals (N, 3), each on the
        texture `texture_index` (N,), interpolated bilinearly between texel centres; outside
        its image a texture repeats."""
        cos, sin = self._cos[texture_index], self._sin[texture_index]
        dx, dy, dz = (points_world[:, axis] - self._origin[axis][texture_index] for axis in range(3))
        # Texture-frame coordinates of the point and the normal (the frame is turned about z).
        x, y = cos * dx + sin * dy, cos * dy - sin * dx
        nx = np.abs(cos * normals_world[:, 0] + sin * normals_world[:, 1])
        ny = np.abs(cos * normals_world[:, 1] - sin * normals_world[:, 0])
        nz = np.abs(normals_world[:, 2])
        # The two coordinates in the face's plane: (x, y) on a face along z, else (y, z) on one
        # along x and (x, z) on one along y.
        along_z, along_x = (nz >= nx) & (nz >= ny), nx > ny
        per_texel = self._per_texel[texture_index]
        u = np.where(along_z | ~along_x, x, y) * per_texel - 0.5
        v = np.where(along_z, y, dz) * per_texel - 0.5
        return self._bilinear(texture_index, u, v)

    def _bilinear(self, texture_index: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        stride = self._stride[texture_index]
        u0, v0 = np.floor(u), np.floor(v)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        column = np.remainder(u0.astype(np.intp), stride - 1)
        row = np.remainder(v0.astype(np.intp), self._height[texture_index])
        k = self._offset[texture_index] + row * stride + column
        texels = self._texels
        low, high = np.take(texels, k, axis=0), np.take(texels, k + stride, axis=0)
        low += (np.take(texels, k + 1, axis=0) - low) * fu
        high += (np.take(texels, k + stride + 1, axis=0) - high) * fu
        return low + (high - low) * fv


# ----------------------------------------------------------------------------------------------
# Noise and patterns (all images are (rows, columns) = (v, u), v up for walls)


def value_noise(shape: tuple[int, int], cell_px: float, rng: np.random.Generator, octaves: int = 4) -> np.ndarray:
    """(H, W) float32 fractal value noise in about [0, 1]: random values on a grid of `cell_px`
    texels, interpolated smoothly, plus `octaves - 1` finer grids at half the cell and half the
    amplitude each. Smooth, so that the image gradient is defined everywhere."""
    height, width = shape
    total = np.zeros(shape, dtype=np.float32)
    amplitude, weight = 1.0, 0.0
    for _ in range(octaves):
        cell = max(cell_px, 1.0)
        grid = rng.random((int(height / cell) + 2, int(width / cell) + 2)).astype(np.float32)
        y, x = np.arange(height) / cell, np.arange(width) / cell
        y0, x0 = y.astype(int), x.astype(int)
        sy, sx = _smoothstep(y - y0)[:, None], _smoothstep(x - x0)[None, :]
        top = grid[y0][:, x0] * (1 - sx) + grid[y0][:, x0 + 1] * sx
        bottom = grid[y0 + 1][:, x0] * (1 - sx) + grid[y0 + 1][:, x0 + 1] * sx
        total += amplitude * (top * (1 - sy) + bottom * sy)
        weight += amplitude
        amplitude, cell_px = amplitude / 2, cell_px / 2
    return total / weight


def _smoothstep(t: np.ndarray) -> np.ndarray:
    return (t * t * (3 - 2 * t)).astype(np.float32)


def _tint(base: np.ndarray, shade: np.ndarray) -> np.ndarray:
    """(H, W, 3) image of colour `base` (3,) scaled per texel by `shade` (H, W)."""
    return np.clip(shade[..., None] * np.asarray(base, dtype=np.float32), 0.0, 1.0)


def _texels(metres: float) -> int:
    return max(2, int(np.ceil(metres / TEXEL_M)))


def wall_image(length_m: float, height_m: float, rng: np.random.Generator) -> np.ndarray:
    """A painted plaster wall: a pale base colour with mottling, a dark skirting board, and a few
    posters of coloured blocks, stripes or discs at eye height."""
    height, width = _texels(height_m), _texels(length_m)
    paint = rng.uniform(0.65, 0.9, size=3)
    image = _tint(paint, 0.85 + 0.3 * value_noise((height, width), 40, rng))
    skirting = min(_texels(0.1), height)
    image[:skirting] = _tint(paint * 0.35, 0.9 + 0.2 * value_noise((skirting, width), 8, rng))
    posters = int(rng.integers(2, 5)) if length_m > 2.0 else 1
    for slot in range(posters):
        poster_w, poster_h = _texels(rng.uniform(0.4, 0.9)), _texels(rng.uniform(0.5, 1.0))
        if poster_w + 2 > width or poster_h + skirting + 2 > height:
            continue
        # One poster per equal slot along the wall, so that posters do not overlap.
        slot_w = width // posters
        u0 = slot * slot_w + int(rng.integers(0, max(1, slot_w - poster_w)))
        v_center = _texels(rng.uniform(1.2, 1.7))
        v0 = int(np.clip(v_center - poster_h // 2, skirting + 1, height - poster_h - 1))
        image[v0:v0 + poster_h, u0:u0 + poster_w] = poster_image(poster_h, poster_w, rng)
    return image


def poster_image(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A framed picture: coloured blocks, stripes or discs on a light ground."""
    border = max(1, min(height, width) // 12)
    image = np.full((height, width, 3), 0.95, dtype=np.float32)
    inner = image[border:height - border, border:width - border]
    h, w = inner.shape[:2]
    style = rng.integers(3)
    palette = rng.uniform(0.05, 0.95, size=(6, 3)).astype(np.float32)
    rows, cols = np.mgrid[0:h, 0:w]
    if style == 0:  # a grid of blocks
        n_rows, n_cols = int(rng.integers(2, 6)), int(rng.integers(2, 6))
        cell = (rows * n_rows // max(h, 1)) * n_cols + cols * n_cols // max(w, 1)
        inner[:] = palette[rng.integers(0, 6, size=n_rows * n_cols)][cell]
    elif style == 1:  # slanted stripes
        period = rng.uniform(6, 20)
        angle = rng.uniform(0, np.pi)
        phase = (cols * np.cos(angle) + rows * np.sin(angle)) / period
        inner[:] = palette[(np.floor(phase).astype(int) % 3)]
    else:  # discs on a ground
        inner[:] = palette[0]
        for k in range(int(rng.integers(3, 8))):
            cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.08, 0.3) * min(h, w)
            inner[(rows - cy) ** 2 + (cols - cx) ** 2 < r * r] = palette[1 + k % 5]
    inner *= (0.9 + 0.2 * value_noise((h, w), 6, rng, octaves=2))[..., None]
    return np.clip(image, 0.0, 1.0)


def floor_image(size_x_m: float, size_y_m: float, rng: np.random.Generator) -> np.ndarray:
    """Ceramic tiles with grout lines, or wooden planks in staggered rows; rows are y, columns x."""
    height, width = _texels(size_y_m), _texels(size_x_m)
    rows, cols = np.mgrid[0:height, 0:width]
    if rng.random() < 0.5:
        tile = _texels(rng.uniform(0.3, 0.6))
        tile_index = (rows // tile) * (width // tile + 1) + cols // tile
        base = rng.uniform(0.35, 0.8, size=3)
        jitter = rng.uniform(0.8, 1.15, size=tile_index.max() + 1).astype(np.float32)
        shade = jitter[tile_index] * (0.85 + 0.3 * value_noise((height, width), 12, rng))
        grout = (rows % tile == 0) | (cols % tile == 0)
        image = _tint(base, shade)
        image[grout] = base * 0.4
        return image
    plank_w, plank_l = _texels(rng.uniform(0.12, 0.22)), _texels(rng.uniform(0.8, 1.6))
    row_of_plank = rows // plank_w
    stagger = rng.integers(0, plank_l, size=row_of_plank.max() + 1)
    plank_index = row_of_plank * (width // plank_l + 2) + (cols + stagger[row_of_plank]) // plank_l
    jitter = rng.uniform(0.75, 1.2, size=plank_index.max() + 1).astype(np.float32)
    grain = wood_grain((height, width), rng, along="x")
    image = _tint(rng.uniform(0.45, 0.7) * np.array([1.0, 0.72, 0.48]), jitter[plank_index] * grain)
    seams = (rows % plank_w == 0) | ((cols + stagger[row_of_plank]) % plank_l == 0)
    image[seams] *= 0.45
    return image


def wood_grain(shape: tuple[int, int], rng: np.random.Generator, along: str = "x") -> np.ndarray:
    """(H, W) float32 shade in about [0.7, 1.15]: growth rings as stripes along `along`, bent by
    noise so that they wander like real grain."""
    height, width = shape
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    across = rows if along == "x" else cols
    warp = value_noise(shape, 60, rng, octaves=3)
    period = rng.uniform(2.0, 4.0)  # texels between rings
    rings = np.sin(2 * np.pi * (across / period + 6.0 * warp)) * 0.5 + 0.5
    fine = value_noise(shape, 4, rng, octaves=2)
    return (0.7 + 0.3 * rings ** 3 + 0.15 * fine).astype(np.float32)


def table_top_image(length_m: float, width_m: float, rng: np.random.Generator) -> np.ndarray:
    """Wood along the table's length (rows along its width, columns along its length)."""
    shape = (_texels(width_m), _texels(length_m))
    colour = rng.uniform(0.45, 0.75) * np.array([1.0, 0.7, 0.45])
    return _tint(colour, wood_grain(shape, rng, along="x"))


# ----------------------------------------------------------------------------------------------
# The room


@dataclass(frozen=True, eq=False)
class RoomTextures:
    """One texture per room mesh, in the order of `Room.meshes()`, and one per table."""

    room: list[SurfaceTexture]
    tables: list[SurfaceTexture]


def _corner(x: float, y: float) -> np.ndarray:
    """The pose of a texture whose origin is the world point (x, y, 0), axes aligned."""
    return make_pose(np.eye(3), np.array([x, y, 0.0]))


def room_textures(room: Room, tables: list[Table], rng: np.random.Generator) -> RoomTextures:
    """Textures for the floor, the four walls and every table top, each image covering its
    surface once (origin at the surface's corner)."""
    lx, ly = room.size_xy
    t, h = room.wall_thickness, room.wall_height
    floor = SurfaceTexture(floor_image(lx + 2 * t, ly + 2 * t, rng), pose_world_texture=_corner(-lx / 2 - t, -ly / 2 - t))
    # Room.meshes(): floor, wall at y-, wall at y+, wall at x-, wall at x+; each wall's image
    # spans its length (x or y) and its height (z).
    walls = [
        SurfaceTexture(wall_image(lx + 2 * t, h, rng), pose_world_texture=_corner(-lx / 2 - t, 0.0)),
        SurfaceTexture(wall_image(lx + 2 * t, h, rng), pose_world_texture=_corner(-lx / 2 - t, 0.0)),
        SurfaceTexture(wall_image(ly, h, rng), pose_world_texture=_corner(0.0, -ly / 2)),
        SurfaceTexture(wall_image(ly, h, rng), pose_world_texture=_corner(0.0, -ly / 2)),
    ]
    table_textures = []
    for table in tables:
        length, width = table.size_xy
        pose = table.pose_world_top @ make_pose(np.eye(3), np.array([-length / 2, -width / 2, 0.0]))
        table_textures.append(SurfaceTexture(table_top_image(length, width, rng), pose_world_texture=pose))
    return RoomTextures([floor, *walls], table_textures)
