"""User mug meshes as files meet them: polygon faces, millimetres and centimetres, y-up exports,
GLB, and shapes too wide for a mug. Every test mesh is written here, in the file format itself."""

import struct

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.sim.mesh_io import MAX_FOOTPRINT_RADIUS, guess_up, load_mug_dir, load_mug_mesh
from ndfa.sim.mug import make_mug


def revolved_cup(radius: float, height: float, segments: int = 48) -> tuple[np.ndarray, list[list[int]]]:
    """A closed cup (wall, rim, cavity, floor) revolved about z, modelled in quads as CAD tools do:
    vertices (V, 3) and faces, quads except the triangle fans at the axis."""
    wall = 0.08 * radius
    profile = [(0.0, 0.0), (radius, 0.0), (radius, height), (radius - wall, height), (radius - wall, wall), (0.0, wall)]
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    vertices, index = [], {}
    for k, (r, z) in enumerate(profile):
        for j, a in enumerate(angles if r > 0 else [0.0]):
            index[k, j] = len(vertices)
            vertices.append((r * np.cos(a), r * np.sin(a), z))
    faces = []
    for k in range(len(profile) - 1):
        for j in range(segments):
            nxt = (j + 1) % segments
            if profile[k][0] == 0:  # fan from the axis point below
                faces.append([index[k, 0], index[k + 1, nxt], index[k + 1, j]])
            elif profile[k + 1][0] == 0:  # fan into the axis point above
                faces.append([index[k, j], index[k, nxt], index[k + 1, 0]])
            else:
                faces.append([index[k, j], index[k, nxt], index[k + 1, nxt], index[k + 1, j]])
    return np.array(vertices), faces


def write_obj(path, vertices, faces) -> None:
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")


def write_binary_stl(path, vertices, triangles) -> None:
    """STL repeats each triangle's corners: the reader has to weld them again."""
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    records = b"".join(struct.pack("<12fH", *n, *c.ravel(), 0) for n, c in zip(normals, corners))
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(triangles)) + records)


def y_up(vertices):
    """z-up vertices as a y-up exporter writes them: (x, y, z) -> (x, z, -y)."""
    return np.c_[vertices[:, 0], vertices[:, 2], -vertices[:, 1]]


def test_quad_faces_are_triangulated_not_dropped(tmp_path):
    vertices, faces = revolved_cup(radius=4.0, height=10.0)  # centimetres
    quads = sum(len(f) == 4 for f in faces)
    assert quads == 3 * 48
    write_obj(tmp_path / "quad_mug.obj", vertices, faces)
    notes = []
    mug = load_mug_mesh(tmp_path / "quad_mug.obj", on_note=notes.append)
    # Open3D's reader kept the 96 fan triangles alone; every quad becomes two triangles
    assert len(mug.mesh.triangles) == 2 * quads + (len(faces) - quads)
    assert mug.watertight and len(mug.parts) == 1
    low, high = mug.mesh.bounds
    np.testing.assert_allclose(high - low, [0.08, 0.08, 0.10], atol=5e-4)  # 10 cm tall, not 90 cm
    assert mug.occupancy(np.array([[0.038, 0.0, 0.05]])).all() and not mug.occupancy(np.array([[0.0, 0.0, 0.05]])).any()
    assert len(notes) == 1 and "centimetres" in notes[0] and "z up" in notes[0]


def test_a_millimetre_stl_keeps_its_real_size(tmp_path):
    mug = make_mug(7)
    write_binary_stl(tmp_path / "mm_mug.stl", 1000.0 * mug.mesh.vertices, mug.mesh.triangles)
    notes = []
    loaded = load_mug_mesh(tmp_path / "mm_mug.stl", on_note=notes.append)
    assert loaded.watertight  # the repeated corners were welded
    assert loaded.mesh.bounds[1][2] == pytest.approx(mug.params.height, abs=1e-6)  # not rescaled to 10 cm
    np.testing.assert_allclose(loaded.mesh.bounds, mug.mesh.bounds, atol=1e-5)
    assert "millimetres" in notes[0]


def test_a_y_up_mesh_is_found_and_turned_upright(tmp_path):
    mug = make_mug(9)
    write_obj(tmp_path / "y_up.obj", y_up(mug.mesh.vertices), mug.mesh.triangles.tolist())
    notes = []
    loaded = load_mug_mesh(tmp_path / "y_up.obj", on_note=notes.append)
    np.testing.assert_allclose(loaded.mesh.bounds, mug.mesh.bounds, atol=1e-6)
    assert notes == ["y_up.obj: y up (guessed; --mesh-up to set it)"]
    with pytest.raises(SimError, match="up axis must be"):
        load_mug_mesh(tmp_path / "y_up.obj", up="x")


@pytest.mark.parametrize("seed", [4, 5, 31, 38, 52])
def test_the_up_guess_holds_whichever_way_the_handle_points(seed):
    mug = make_mug(seed).mesh
    for angle in np.linspace(0, 2 * np.pi, 7, endpoint=False):
        c, s = np.cos(angle), np.sin(angle)
        v = mug.vertices @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
        assert guess_up(v, mug.triangles) == "z"
        assert guess_up(y_up(v), mug.triangles) == "y"


def test_glb_loads(tmp_path):
    import trimesh

    mug = make_mug(3)
    trimesh.Trimesh(mug.mesh.vertices, mug.mesh.triangles).export(tmp_path / "mug.glb")
    loaded = load_mug_mesh(tmp_path / "mug.glb", up="z")
    assert loaded.watertight
    np.testing.assert_allclose(loaded.mesh.bounds, mug.mesh.bounds, atol=1e-5)


def test_too_wide_meshes_are_narrowed_to_fit_the_tables_or_refused(tmp_path):
    from ndfa.sim.presets import make_config
    from ndfa.sim.table_space import footprint_radius
    from ndfa.sim.world import build_world

    for i in range(4):  # bowls: 40 cm across, 10 cm tall (metres)
        vertices, faces = revolved_cup(radius=0.20, height=0.10 + 0.005 * i)
        write_obj(tmp_path / f"bowl{i}.obj", vertices, faces)
    notes = []
    models = load_mug_dir(tmp_path, on_note=notes.append)
    assert all(footprint_radius(m) == pytest.approx(MAX_FOOTPRINT_RADIUS) for m in models)
    assert all("scaled to 20 cm across" in note for note in notes)
    world = build_world(make_config("paper", 0), models)  # before: "cannot fit 4 mugs on table 1"
    assert len(world.source) >= 4

    plate = tmp_path / "plate" / "plate.obj"
    plate.parent.mkdir()
    write_obj(plate, *revolved_cup(radius=0.15, height=0.02))
    with pytest.raises(SimError, match="plate.obj: not mug-shaped"):
        load_mug_mesh(plate)


@pytest.mark.parametrize("name, content", [
    ("binary.obj", bytes(range(256)) * 4),
    ("points.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"),
    ("cut.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nend_header\n\x00\x01"),
    ("short.stl", b"\0" * 80 + struct.pack("<I", 1000) + b"\1" * 10),
    ("broken.glb", b"glTF\x02\x00\x00\x00" + b"\xff" * 40),
    ("nan.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
])
def test_broken_mesh_files_fail_in_one_line_naming_the_file(tmp_path, name, content):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(SimError, match=name) as error:
        load_mug_mesh(tmp_path / name)
    assert "\n" not in str(error.value)


def test_what_the_mesh_fuzzer_found_fails_in_one_line(tmp_path):
    """A vertex line short of a coordinate (trimesh then gives 2-D points), and coordinates far
    beyond any unit (trimesh's casts of them warned, and their hull meant nothing)."""
    import warnings

    vertices, faces = revolved_cup(0.04, 0.09)
    write_obj(tmp_path / "short.obj", vertices, faces)
    text = (tmp_path / "short.obj").read_text().splitlines()
    (tmp_path / "short.obj").write_text("\n".join(["v 0.1 0.2"] * 3 + text[3:]) + "\n")
    with pytest.raises(SimError, match=r"short\.obj: .*(3-D points|cannot read)"):
        load_mug_mesh(tmp_path / "short.obj")
    mug = make_mug(3).mesh
    write_binary_stl(tmp_path / "huge.stl", np.vstack([mug.vertices, [[3e37, 0, 0]]]),
                     np.vstack([mug.triangles, [[0, 1, len(mug.vertices)]]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one line, no library warning beside it
        with pytest.raises(SimError, match=r"huge\.stl: coordinates up to 3e\+37"):
            load_mug_mesh(tmp_path / "huge.stl")
