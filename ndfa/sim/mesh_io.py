"""User-supplied mug meshes (OBJ, PLY, STL) as `Mug`s in the mug frame.

The mug frame is the one procedural mugs use (see `ndfa.sim.mug`): z up, metres, base at z = 0,
body axis on the z axis, handle on +x. A loaded mesh is brought into it by

1. turning y-up files (`up="y"`, common for OBJ exports) to z-up;
2. scaling: a height of 6-13 cm is taken to be metres already and kept; any other height is
   taken to be another unit (millimetres, centimetres, an arbitrary modelling scale) and the mesh
   is scaled uniformly to a 10 cm mug;
3. moving the body's axis to x = y = 0: the axis is the centre of the xy bounding box of the
   vertices in the lowest 20% of the height, where only the base is, not the handle;
4. moving the base to z = 0;
5. turning it about z so that the part farthest from the axis (the handle, if there is one)
   lies on +x: the mean of the vertices in the outermost centimetre.

Each connected piece of the mesh becomes one part, so a body and a handle modelled as separate
overlapping shells keep exact occupancy. A mesh with a piece that is not closed still loads (it
renders fine) with `watertight=False` and a warning; its `occupancy` raises.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.mesh import Mesh
from ndfa.sim.mug import Mug

MESH_SUFFIXES = (".obj", ".ply", ".stl")
MUG_HEIGHT_RANGE = (0.06, 0.13)  # metres; heights in this range are kept as they are
DEFAULT_HEIGHT = 0.10  # metres; height of a mesh whose units had to be guessed
BASE_BAND = 0.2  # fraction of the height, from the bottom, used to find the body's axis


def load_mug_mesh(path: Path, *, up: str = "z") -> Mug:
    """The mug in the mesh file `path`, in the mug frame. `up` is the file's up axis, "z" or "y"."""
    path = Path(path)
    if up not in ("z", "y"):
        raise SimError(f"{path}: up axis must be 'z' or 'y', not {up!r}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SimError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {', '.join(MESH_SUFFIXES)}")
    if not path.is_file():
        raise SimError(f"{path}: no such file")
    vertices, triangles = _read_triangles(path)
    vertices = to_mug_frame(vertices, up, path)
    parts = connected_parts(vertices, triangles)
    watertight = all(is_closed_manifold(part) for part in parts)
    if not watertight:
        warnings.warn(
            f"{path}: mesh is not watertight (it has open edges or non-manifold parts); it can be "
            "rendered, but exact occupancy is unavailable for it",
            stacklevel=2,
        )
    return Mug(model_id=f"file:{path.stem}", seed=-1, params=None, parts=parts, watertight=watertight)


def load_mug_dir(directory: Path, up: str = "z") -> list[Mug]:
    """Every mesh file (.obj, .ply, .stl) directly in `directory`, sorted by file name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SimError(f"{directory}: no such directory")
    files = sorted(f for f in directory.iterdir() if f.is_file() and f.suffix.lower() in MESH_SUFFIXES)
    if not files:
        raise SimError(f"{directory}: no mesh files ({', '.join(MESH_SUFFIXES)}) in it")
    stems = [f.stem for f in files]
    duplicates = sorted({s for s in stems if stems.count(s) > 1})
    if duplicates:  # model ids are "file:{stem}" and must be unique
        raise SimError(f"{directory}: several mesh files share a name: {', '.join(duplicates)}")
    return [load_mug_mesh(f, up=up) for f in files]


def _read_triangles(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangles (F, 3) int32 of a mesh file, in the file's units."""
    import open3d as o3d

    if path.stat().st_size == 0:
        raise SimError(f"{path}: empty file")
    try:
        with _native_stderr_silenced():
            mesh = o3d.io.read_triangle_mesh(str(path))
    except Exception as error:  # Open3D raises plain RuntimeErrors for some broken files
        raise SimError(f"{path}: cannot read mesh: {error}") from error
    if len(mesh.triangles) == 0:
        raise SimError(f"{path}: no triangles in it (unreadable, empty or not a triangle mesh)")
    # STL stores each triangle with its own three corners: merge equal corners so neighbouring
    # triangles share edges (otherwise no STL mesh would ever be closed).
    mesh.remove_duplicated_vertices()
    mesh.remove_unreferenced_vertices()
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise SimError(f"{path}: vertices with NaN or infinite coordinates")
    return vertices.copy(), np.asarray(mesh.triangles, dtype=np.int32).copy()


@contextlib.contextmanager
def _native_stderr_silenced():
    """Open3D's file readers print their own complaints from C++ (e.g. RPly's "Unable to read
    magic number"); we report the problem ourselves in one line, so theirs is dropped."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def to_mug_frame(vertices: np.ndarray, up: str, path: Path) -> np.ndarray:
    """`vertices` (V, 3) of a file with up axis `up`, moved into the mug frame (module docstring)."""
    if up == "y":  # +90 degrees about x: file y (up) becomes z, file z becomes -y
        vertices = np.c_[vertices[:, 0], -vertices[:, 2], vertices[:, 1]]
    height = np.ptp(vertices[:, 2])
    if height <= 0:
        raise SimError(f"{path}: the mesh is flat (zero height along the up axis {up!r})")
    if not MUG_HEIGHT_RANGE[0] <= height <= MUG_HEIGHT_RANGE[1]:
        vertices = vertices * (DEFAULT_HEIGHT / height)
        height = DEFAULT_HEIGHT
    bottom = vertices[:, 2].min()
    base = vertices[vertices[:, 2] <= bottom + BASE_BAND * height]
    axis_xy = (base[:, :2].min(axis=0) + base[:, :2].max(axis=0)) / 2
    vertices = vertices - np.array([axis_xy[0], axis_xy[1], bottom])
    # The handle sticks out farthest from the axis: point the mean of the outermost centimetre at +x.
    distance = np.linalg.norm(vertices[:, :2], axis=1)
    handle_xy = vertices[distance >= distance.max() - 0.01, :2].mean(axis=0)
    angle = -np.arctan2(handle_xy[1], handle_xy[0])
    c, s = np.cos(angle), np.sin(angle)
    return np.c_[c * vertices[:, 0] - s * vertices[:, 1], s * vertices[:, 0] + c * vertices[:, 1], vertices[:, 2]]


def connected_parts(vertices: np.ndarray, triangles: np.ndarray) -> list[Mesh]:
    """The mesh split into its connected pieces (triangles sharing vertices), each re-indexed."""
    labels = np.asarray(Mesh(vertices, triangles).to_open3d().cluster_connected_triangles()[0])
    parts = []
    for label in np.unique(labels):
        part_triangles = triangles[labels == label]
        used, remapped = np.unique(part_triangles, return_inverse=True)
        parts.append(Mesh(vertices[used], remapped.reshape(-1, 3).astype(np.int32)))
    return parts


def is_closed_manifold(mesh: Mesh) -> bool:
    """Every edge shared by exactly two triangles and every vertex a single fan: enough for
    ray-parity occupancy. (`Mesh.is_watertight` also tests self-intersections, but that test
    takes time quadratic in the triangles: minutes for a detailed scanned mug.)"""
    legacy = mesh.to_open3d()
    return bool(legacy.is_edge_manifold(allow_boundary_edges=False) and legacy.is_vertex_manifold())
