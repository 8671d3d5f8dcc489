"""Broken mesh files for `--mesh-dir`: a real procedural mug written by trimesh in each format the
loader reads, then mutated (cut, bit-flipped, or for OBJ edited line by line: numbers made NaN,
infinite, huge or zero, face indices out of range, lines dropped or repeated), or scaled to odd
units."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from hypothesis import strategies as st

from tests.fuzz.property import Blob

FORMATS = (".obj", ".ply", ".stl", ".glb")


@lru_cache(maxsize=None)
def mug_file(suffix: str, scale: float = 1.0) -> bytes:
    """A procedural mug (seed 3) as the bytes of a `suffix` file, its coordinates times `scale`."""
    import trimesh

    from ndfa.sim.mug import make_mug

    mesh = make_mug(3).mesh
    surface = trimesh.Trimesh(mesh.vertices * scale, mesh.triangles, process=False)
    exported = surface.export(file_type=suffix.lstrip("."))
    return exported.encode() if isinstance(exported, str) else bytes(exported)


def _edit_obj(text: str, edits: list[tuple[str, int, str]]) -> str:
    lines = text.splitlines()
    for kind, position, value in edits:
        if not lines:
            break
        i = position % len(lines)
        if kind == "drop":
            del lines[i]
        elif kind == "repeat":
            lines.insert(i, lines[i])
        else:  # "number": one field of the line replaced
            fields = lines[i].split()
            if len(fields) > 1:
                fields[1 + position % (len(fields) - 1)] = value
                lines[i] = " ".join(fields)
    return "\n".join(lines) + "\n"


FIELDS = st.sampled_from(["nan", "inf", "-inf", "1e308", "0", "-1", "999999", "x", "", "1/2/3", "3.5.6"])


@st.composite
def mesh_files(draw) -> tuple[str, Blob]:
    """(suffix, file bytes) of a broken or odd mesh."""
    suffix = draw(st.sampled_from(FORMATS))
    scale = draw(st.sampled_from([1.0, 1.0, 1.0, 1000.0, 100.0, 1e-4, 50.0, 0.0]))
    data = mug_file(suffix, scale)
    how = draw(st.sampled_from(["cut", "flip", "edit", "as is"] if suffix == ".obj" else ["cut", "flip", "as is"]))
    if how == "cut":
        data = data[: draw(st.integers(0, len(data)))]
    elif how == "flip":
        flipped = bytearray(data)
        for position in draw(st.lists(st.integers(0, len(data) - 1), min_size=1, max_size=8)):
            flipped[position] ^= 1 << draw(st.integers(0, 7))
        data = bytes(flipped)
    elif how == "edit":
        edits = draw(st.lists(st.tuples(st.sampled_from(["drop", "repeat", "number"]), st.integers(0, 10**6), FIELDS),
                              min_size=1, max_size=6))
        data = _edit_obj(data.decode(), edits).encode()
    return suffix, Blob(data)


def finite_mug(mug) -> bool:  # noqa: ANN001 - ndfa.sim.mug.Mug
    """A loaded mug is sane: finite vertices, triangles that index them, mug-sized."""
    for part in mug.parts:
        if not np.all(np.isfinite(part.vertices)) or len(part.triangles) == 0:
            return False
        if part.triangles.min() < 0 or part.triangles.max() >= len(part.vertices):
            return False
    extent = np.ptp(np.concatenate([p.vertices for p in mug.parts]), axis=0)
    return bool(np.all(extent <= 0.25))
