"""User-supplied mug meshes (OBJ, PLY, STL, GLB) as `Mug`s in the mug frame.

Files are read with trimesh, which triangulates polygon faces (Open3D's readers drop every face
that is not a triangle: a mug modelled in quads lost most of its surface) and merges the corners
that STL repeats per triangle. The mug frame is the one procedural mugs use (see `ndfa.sim.mug`):
z up, metres, base at z = 0, body axis on the z axis, handle on +x. A loaded mesh is brought into
it by

1. turning its up axis to z. `up="auto"` guesses it: a mug's convex hull has two large flat faces,
   its base and the disc over its rim, both square to up, while its wall is round and its handle
   curved; so of the file's y and z (the two conventions in the wild), up is the one the largest
   flat face of the hull faces;
2. guessing its unit: the height (along up) that is a mug's (4-25 cm) in metres, centimetres or
   millimetres gives the unit; a height in none of them (or outside 6-13 cm once in metres) is an
   arbitrary modelling scale, and the mesh is scaled uniformly to a 10 cm mug;
3. moving the body's axis to x = y = 0: the axis is the centre of the xy bounding box of the
   vertices in the lowest 20% of the height, where only the base is, not the handle;
4. moving the base to z = 0;
5. turning it about z so that the part farthest from the axis (the handle, if there is one)
   lies on +x: the mean of the vertices in the outermost centimetre;
6. keeping it placeable: a mesh wider than a mug (more than 20 cm across, handle included) would
   not fit the tables with the others, so it is scaled down to that width, or refused when that
   would leave it under 4 cm tall (it is not mug-shaped).

Each step that guessed or changed something is said in one note per mesh (`on_note`).

Each connected piece of the mesh becomes one part, so a body and a handle modelled as separate
overlapping shells keep exact occupancy. A mesh with a piece that is not closed still loads (it
renders fine) with `watertight=False` and a warning; its `occupancy` raises.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.mesh import Mesh
from ndfa.sim.mug import Mug

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb")
UP_AXES = ("auto", "z", "y")
MUG_HEIGHT_RANGE = (0.06, 0.13)  # metres; heights in this range are kept as they are
PLAUSIBLE_HEIGHT = (0.04, 0.25)  # metres; a height in this range in some unit tells the unit
UNITS = (("metres", 1.0), ("centimetres", 0.01), ("millimetres", 0.001))
DEFAULT_HEIGHT = 0.10  # metres; height of a mesh whose units had to be guessed
MAX_FOOTPRINT_RADIUS = 0.10  # metres; from the body axis to the farthest point seen from above
MIN_HEIGHT = 0.04  # metres; a mesh this low once narrowed to MAX_FOOTPRINT_RADIUS is refused
END_COSINE = 0.99  # a hull face is an end of the mug along an axis when its normal is this close to it
MAX_COORDINATE = 1e5  # file units; a mug in millimetres stays within a few hundred
BASE_BAND = 0.2  # fraction of the height, from the bottom, used to find the body's axis

Notes = Callable[[str], None]


def load_mug_mesh(path: Path, *, up: str = "auto", on_note: Notes | None = None) -> Mug:
    """The mug in the mesh file `path`, in the mug frame. `up` is the file's up axis: "z", "y" or
    "auto" (guessed); `on_note` hears what was guessed or changed, one line."""
    path = Path(path)
    if up not in UP_AXES:
        raise SimError(f"{path}: up axis must be one of {', '.join(UP_AXES)}, not {up!r}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SimError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {', '.join(MESH_SUFFIXES)}")
    if not path.is_file():
        raise SimError(f"{path}: no such file")
    vertices, triangles = _read_triangles(path)
    notes: list[str] = []
    if up == "auto":
        up = guess_up(vertices, triangles)
        notes.append(f"{up} up (guessed; --mesh-up to set it)")
    vertices = to_mug_frame(vertices, up, path, notes)
    if notes and on_note is not None:
        on_note(f"{path.name}: " + "; ".join(notes))
    parts = connected_parts(vertices, triangles)
    watertight = all(is_closed_manifold(part) for part in parts)
    if not watertight:
        warnings.warn(
            f"{path}: mesh is not watertight (it has open edges or non-manifold parts); it can be "
            "rendered, but exact occupancy is unavailable for it",
            stacklevel=2,
        )
    return Mug(model_id=f"file:{path.stem}", seed=-1, params=None, parts=parts, watertight=watertight)


def load_mug_dir(directory: Path, up: str = "auto", on_note: Notes | None = None) -> list[Mug]:
    """Every mesh file (.obj, .ply, .stl, .glb) directly in `directory`, sorted by file name."""
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
    return [load_mug_mesh(f, up=up, on_note=on_note) for f in files]


def _read_triangles(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangles (F, 3) int32 of a mesh file, in the file's units."""
    import trimesh

    if path.stat().st_size == 0:
        raise SimError(f"{path}: empty file")
    logging.getLogger("trimesh").setLevel(logging.CRITICAL)  # we say what is wrong, in one line
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            # trimesh casts absurd coordinates with a RuntimeWarning; the checks below say what is wrong
            warnings.simplefilter("ignore", RuntimeWarning)
            # force="mesh": a GLB scene's meshes, each moved by its node's transform, as one mesh
            mesh = trimesh.load(str(path), force="mesh", process=False)
            if not isinstance(mesh, trimesh.Trimesh):
                raise ValueError(f"holds a {type(mesh).__name__}, not a surface")
            if np.ndim(mesh.vertices) != 2 or np.shape(mesh.vertices)[1] != 3:  # an OBJ "v" line short of a coordinate
                raise SimError(f"{path}: vertices are not 3-D points (a coordinate missing?)")
            if not np.all(np.isfinite(mesh.vertices)):
                raise SimError(f"{path}: vertices with NaN or infinite coordinates")
            if len(mesh.vertices) and (largest := float(np.abs(mesh.vertices).max())) > MAX_COORDINATE:
                raise SimError(f"{path}: coordinates up to {largest:.3g}: no mug in metres, centimetres or millimetres")
            # Weld corners by position alone: STL repeats them per triangle, and OBJ splits them
            # along texture seams; either way no mesh would ever be closed.
            mesh.merge_vertices(merge_tex=True, merge_norm=True)
    except SimError:
        raise
    except Exception as error:  # trimesh's readers raise whatever the parser hit
        lines = str(error).strip().splitlines()
        raise SimError(f"{path}: cannot read mesh ({lines[0][:160] if lines else type(error).__name__})") from None
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        raise SimError(f"{path}: no faces in it (unreadable, empty or only points)")
    used = np.unique(triangles)  # drop vertices no face uses (they would count in the extent)
    remap = np.zeros(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used].copy(), remap[triangles].astype(np.int32)


def guess_up(vertices: np.ndarray, triangles: np.ndarray) -> str:
    """"z" or "y": the file axis along which the mesh's convex hull has large flat faces at both
    ends, the base and the disc over the rim (module docstring). Flat faces over a handle come in
    pairs too, but mirrored about the handle, never facing opposite ways along one axis."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)  # degenerate hulls: the fallback below
            hull = mesh.convex_hull
            # coplanar hull triangles merged into facets, and single triangles: the flat pieces
            areas = np.concatenate([hull.facets_area, hull.area_faces])
            normals = np.concatenate([np.reshape(hull.facets_normal, (-1, 3)), hull.face_normals])
    except Exception:  # a flat or degenerate mesh has no hull: its own faces vote instead
        areas, normals = mesh.area_faces, mesh.face_normals

    def both_ends(axis: int) -> float:
        """The smaller of the largest flat piece facing +axis and the largest facing -axis."""
        return min(float(areas[sign * normals[:, axis] >= END_COSINE].max(initial=0.0)) for sign in (1, -1))

    return "y" if both_ends(1) > both_ends(2) else "z"


def to_mug_frame(vertices: np.ndarray, up: str, path: Path, notes: list[str] | None = None) -> np.ndarray:
    """`vertices` (V, 3) of a file with up axis `up`, moved into the mug frame (module docstring);
    `notes` collects what was guessed or changed."""
    notes = [] if notes is None else notes
    if up == "y":  # +90 degrees about x: file y (up) becomes z, file z becomes -y
        vertices = np.c_[vertices[:, 0], -vertices[:, 2], vertices[:, 1]]
    height = float(np.ptp(vertices[:, 2]))
    if height <= 0:
        raise SimError(f"{path}: the mesh is flat (zero height along the up axis {up!r})")
    unit = next(((name, scale) for name, scale in UNITS
                 if PLAUSIBLE_HEIGHT[0] <= height * scale <= PLAUSIBLE_HEIGHT[1]), None)
    if unit is not None and unit[1] != 1.0:
        vertices, height = vertices * unit[1], height * unit[1]
        notes.append(f"{unit[0]} (guessed from its height, {height * 100:.1f} cm)")
    if not MUG_HEIGHT_RANGE[0] <= height <= MUG_HEIGHT_RANGE[1]:
        notes.append(f"{height:.4g} {'m' if unit else 'units'} tall, not a mug's "
                     f"{MUG_HEIGHT_RANGE[0] * 100:g}-{MUG_HEIGHT_RANGE[1] * 100:g} cm: scaled to {DEFAULT_HEIGHT * 100:g} cm")
        vertices = vertices * (DEFAULT_HEIGHT / height)
        height = DEFAULT_HEIGHT
    bottom = vertices[:, 2].min()
    base = vertices[vertices[:, 2] <= bottom + BASE_BAND * height]
    axis_xy = (base[:, :2].min(axis=0) + base[:, :2].max(axis=0)) / 2
    vertices = vertices - np.array([axis_xy[0], axis_xy[1], bottom])
    radius = float(np.linalg.norm(vertices[:, :2], axis=1).max())
    if radius > MAX_FOOTPRINT_RADIUS:
        shrink = MAX_FOOTPRINT_RADIUS / radius
        if height * shrink < MIN_HEIGHT:
            raise SimError(f"{path}: not mug-shaped: {2 * radius * 100:.0f} cm across for {height * 100:.0f} cm of "
                           f"height; narrowed to the {2 * MAX_FOOTPRINT_RADIUS * 100:.0f} cm a mug may take on the "
                           f"tables it would be {height * shrink * 100:.1f} cm tall (at least {MIN_HEIGHT * 100:g})")
        notes.append(f"{2 * radius * 100:.0f} cm across (handle included), wider than a mug: scaled to "
                     f"{2 * MAX_FOOTPRINT_RADIUS * 100:.0f} cm across, {height * shrink * 100:.1f} cm tall")
        vertices, height = vertices * shrink, height * shrink
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
