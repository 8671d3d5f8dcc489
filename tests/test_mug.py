"""Procedural mugs, the train/test split and loading user meshes."""

from __future__ import annotations

from collections import Counter
from functools import cache

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.core.geometry import rotation_z
from ndfa.sim.mesh import Mesh
from ndfa.sim.mesh_io import load_mug_dir, load_mug_mesh
from ndfa.sim.mug import (
    BASE_STYLES,
    HANDLE_SHAPES,
    PROFILES,
    Mug,
    handle_centerline,
    inner_radius,
    make_mug,
    outer_radius,
    sample_mug_params,
)
from ndfa.sim.splits import TEST_SEEDS, TRAIN_SEEDS, make_split_mug, split_seed

SPLIT_INDICES = [("train", i) for i in range(40)] + [("test", i) for i in range(40)]


@cache
def split_mug(split: str, index: int) -> Mug:
    return make_split_mug(split, index)


def all_mugs() -> list[Mug]:
    return [split_mug(split, index) for split, index in SPLIT_INDICES]


# ---------------------------------------------------------------------------------------------
# Shape


@pytest.mark.parametrize("split, index", SPLIT_INDICES)
def test_every_part_is_watertight(split, index):
    mug = split_mug(split, index)
    assert mug.watertight
    assert len(mug.parts) == (1 if mug.params.handle_shape == "none" else 2)
    for part in mug.parts:
        assert part.vertices.dtype == np.float64 and part.triangles.dtype == np.int32
        assert part.is_watertight()


def test_parts_wind_outward():
    for mug in all_mugs():
        for part in mug.parts:
            corners = part.vertices[part.triangles]  # (F, 3 corners, 3)
            signed_volume = np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6
            assert signed_volume > 0


def test_dimensions_are_those_of_a_mug():
    for mug in all_mugs():
        p, body = mug.params, mug.parts[0]
        low, high = mug.mesh.bounds
        assert low[2] == pytest.approx(0.0, abs=1e-9)  # base at z = 0
        assert 0.06 <= high[2] <= 0.13
        assert high[2] == pytest.approx(p.height)
        body_radius = np.linalg.norm(body.vertices[:, :2], axis=1).max()
        assert 0.03 - 1e-6 <= body_radius <= 0.055 + 1e-6
        assert 0.003 <= p.wall_thickness <= 0.008
        assert np.abs(body.bounds[0][:2] + body.bounds[1][:2]).max() < 1e-9  # axis on z
        if p.handle_shape != "none":  # handle on +x, centred on the xz plane, beyond the body
            handle = mug.parts[1]
            assert handle.vertices[:, 0].min() > 0
            assert np.abs(handle.vertices[:, 1]).max() <= p.handle_width / 2 + 1e-9
            z_mid = (p.handle_bottom_z + p.handle_top_z) / 2
            assert handle.vertices[:, 0].max() > outer_radius(p, np.array([z_mid]))[0] + 0.01


def test_meshes_stay_small():
    for mug in all_mugs():
        assert len(mug.mesh.triangles) < 6000


def test_same_seed_same_mug():
    a, b = make_mug(1234), make_mug(1234)
    assert a.params == b.params and a.model_id == b.model_id == "mug-0001234"
    for part_a, part_b in zip(a.parts, b.parts, strict=True):
        np.testing.assert_array_equal(part_a.vertices, part_b.vertices)
        np.testing.assert_array_equal(part_a.triangles, part_b.triangles)
    assert make_mug(1235).params != a.params


def test_all_kinds_of_mug_occur():
    params = [sample_mug_params(np.random.default_rng(seed)) for seed in range(400)]
    handles = Counter(p.handle_shape for p in params)
    assert {p.profile for p in params} == set(PROFILES)
    assert {p.base_style for p in params} == set(BASE_STYLES)
    assert set(handles) == set(HANDLE_SHAPES)
    assert handles["none"] < 0.1 * len(params)  # handle-less mugs are a rare sub-type
    tapered = [p.bottom_radius_ratio for p in params if p.profile == "tapered"]
    assert min(tapered) < 1 < max(tapered)  # narrower at the bottom and narrower at the top
    assert any(p.lip_flare > 0 for p in params) and any(p.lip_flare == 0 for p in params)
    handled = [p for p in params if p.handle_shape != "none"]
    assert any(p.handle_width == p.handle_thickness for p in handled)  # round cross-section
    assert any(p.handle_width > p.handle_thickness for p in handled)  # elliptic cross-section


# ---------------------------------------------------------------------------------------------
# Occupancy


def _probes(mug: Mug) -> dict[str, tuple[np.ndarray, bool]]:
    """Named points (N, 3) in the mug frame and whether they must be occupied."""
    p = mug.params
    # Wall heights clear of the base's corner and the rim; angles clear of the handle on +x.
    z = np.linspace(p.base_thickness + p.inner_fillet + 0.003, p.height - p.wall_thickness - 0.002, 5)
    angles = np.radians([60.0, 135.0, 200.0, 290.0])
    zz, aa = (g.ravel() for g in np.meshgrid(z, angles))
    ring = lambda r: np.c_[r * np.cos(aa), r * np.sin(aa), zz]  # noqa: E731
    mid_wall = (outer_radius(p, zz) + inner_radius(p, zz)) / 2
    floor_z = (p.recess_depth + p.base_thickness) / 2
    probes = {
        "mid-wall": (ring(mid_wall), True),
        "1 mm outside the wall": (ring(outer_radius(p, zz) + 0.001), False),
        "cavity, on the axis half way up": (np.array([[0.0, 0.0, (p.base_thickness + p.height) / 2]]), False),
        "inside the base": (np.array([[0.0, 0.004, floor_z], [-0.004, 0.0, floor_z]]), True),
    }
    if p.handle_shape != "none":
        points, _ = handle_centerline(p)
        z_mid = (p.handle_bottom_z + p.handle_top_z) / 2
        # The centre-line crosses the mid height once, on the grip.
        k = np.flatnonzero(np.diff(np.sign(points[:, 2] - z_mid)))[0]
        f = (z_mid - points[k, 2]) / (points[k + 1, 2] - points[k, 2])
        grip = points[k] + f * (points[k + 1] - points[k])
        wall = float(outer_radius(p, np.array([z_mid]))[0])
        hole = np.array([(wall + grip[0] - p.handle_thickness / 2) / 2, 0.0, z_mid])
        probes["centre of the handle's tube"] = (grip[None], True)
        probes["centre of the handle's hole"] = (hole[None], False)
        # The buried ends lie inside body and handle at once: a single parity scene would miss them.
        probes["buried ends of the handle"] = (points[[0, -1]], True)
    return probes


@pytest.mark.parametrize("split, index", SPLIT_INDICES[::2])
def test_occupancy_agrees_with_the_shape(split, index):
    mug = split_mug(split, index)
    for name, (points, occupied) in _probes(mug).items():
        inside = mug.occupancy(points)
        assert inside.shape == (len(points),) and inside.dtype == bool
        assert np.all(inside == occupied), f"{mug.model_id}: {name} should be {'in' if occupied else 'out'}side"


def test_handle_ends_are_buried_in_the_wall():
    """The end caps lie inside the body's material (not in the cavity, not outside): body and
    handle make one solid."""
    for mug in all_mugs():
        p = mug.params
        if p.handle_shape == "none":
            continue
        body_only = Mug("body", mug.seed, p, mug.parts[:1])
        points, tangents = handle_centerline(p)
        for end, tangent in ((points[0], tangents[0]), (points[-1], tangents[-1])):
            in_plane = np.cross([0.0, 1.0, 0.0], tangent)
            across = np.array([0.0, 1.0, 0.0])
            cap = end + np.array([[0.0, 0.0, 0.0]] + [s * p.handle_thickness / 2 * in_plane for s in (-1, 1)]
                                 + [s * p.handle_width / 2 * across for s in (-1, 1)])
            assert body_only.occupancy(cap).all(), f"{mug.model_id}: handle end not buried in the wall"


def test_occupancy_needs_a_watertight_mesh():
    mug = make_mug(7)
    open_mug = Mug("file:open", -1, None, mug.parts, watertight=False)
    with pytest.raises(SimError, match="file:open.*occupancy is unavailable"):
        open_mug.occupancy(np.zeros((1, 3)))


# ---------------------------------------------------------------------------------------------
# Train / test split


def test_train_and_test_seeds_are_disjoint():
    assert set(TRAIN_SEEDS).isdisjoint(TEST_SEEDS)
    assert split_seed("train", 0) == TRAIN_SEEDS[0] and split_seed("test", 0) == TEST_SEEDS[0]
    assert split_seed("test", len(TEST_SEEDS) - 1) == TEST_SEEDS[-1]
    assert make_split_mug("test", 3).model_id == f"mug-{TEST_SEEDS[3]:07d}"


@pytest.mark.parametrize("split, index", [("val", 0), ("train", -1), ("test", len(TEST_SEEDS))])
def test_bad_split_or_index_raises(split, index):
    with pytest.raises(SimError, match="split|range"):
        split_seed(split, index)


# ---------------------------------------------------------------------------------------------
# Loading user meshes


def _write(mesh: Mesh, path) -> None:
    import open3d as o3d

    legacy = mesh.to_open3d()
    legacy.compute_triangle_normals()  # the STL writer needs them
    assert o3d.io.write_triangle_mesh(str(path), legacy)


def test_loading_rescales_turns_and_centres_a_mesh(tmp_path):
    mug = make_mug(11)
    # Handle turned away from +x, into a y-up file frame ((x, y, z) -> (x, z, -y)), ten times
    # too big, off-centre.
    v = mug.mesh.vertices @ rotation_z(0.8).T
    file_vertices = 10.0 * np.c_[v[:, 0], v[:, 2], -v[:, 1]] + np.array([0.3, -0.2, 0.5])
    path = tmp_path / "big_mug.ply"
    _write(Mesh(file_vertices, mug.mesh.triangles), path)

    loaded = load_mug_mesh(path, up="y")
    assert loaded.model_id == "file:big_mug" and loaded.seed == -1 and loaded.params is None
    assert loaded.watertight and len(loaded.parts) == 2  # body and handle, as separate shells
    scale = 0.1 / mug.params.height  # height outside 6-13 cm: rescaled to 10 cm
    low, high = loaded.mesh.bounds
    np.testing.assert_allclose(low, scale * mug.mesh.bounds[0], atol=1e-6)
    np.testing.assert_allclose(high, scale * mug.mesh.bounds[1], atol=1e-6)
    assert high[2] == pytest.approx(0.1) and low[2] == pytest.approx(0.0, abs=1e-9)
    probes = _probes(mug)
    points, _ = probes["centre of the handle's tube"]
    assert loaded.occupancy(scale * points).all()  # handle back on +x, still solid


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl"])
def test_loading_keeps_a_mug_sized_mesh(tmp_path, suffix):
    mug = make_mug(5)
    path = tmp_path / f"mug{suffix}"
    _write(mug.mesh.transformed(np.array([[1, 0, 0, 0.2], [0, 1, 0, 0.1], [0, 0, 1, 0.7], [0, 0, 0, 1.0]])), path)
    loaded = load_mug_mesh(path)
    assert loaded.watertight  # STL corners were merged back into shared vertices
    np.testing.assert_allclose(loaded.mesh.bounds[0], mug.mesh.bounds[0], atol=1e-6)
    np.testing.assert_allclose(loaded.mesh.bounds[1], mug.mesh.bounds[1], atol=1e-6)


def test_an_open_mesh_loads_with_a_warning(tmp_path):
    body = make_mug(5).parts[0]
    path = tmp_path / "open.ply"
    _write(Mesh(body.vertices, body.triangles[10:]), path)
    with pytest.warns(UserWarning, match="open.ply.*not watertight"):
        loaded = load_mug_mesh(path)
    assert not loaded.watertight and len(loaded.mesh.triangles) == len(body.triangles) - 10
    with pytest.raises(SimError, match="occupancy is unavailable"):
        loaded.occupancy(np.zeros((1, 3)))


def test_load_a_directory(tmp_path):
    for seed, name in ((3, "b.ply"), (4, "a.obj")):
        _write(make_mug(seed).mesh, tmp_path / name)
    (tmp_path / "notes.txt").write_text("not a mesh")
    mugs = load_mug_dir(tmp_path)
    assert [m.model_id for m in mugs] == ["file:a", "file:b"]


@pytest.mark.parametrize(
    "name, content",
    [("empty.ply", b""), ("garbage.obj", b"this is not a mesh\n\x00\xff"), ("garbage.stl", b"\x01" * 20)],
)
def test_unreadable_files_raise(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(SimError, match=name):
        load_mug_mesh(path)


def test_bad_paths_raise(tmp_path):
    with pytest.raises(SimError, match="mug.dae.*unsupported"):
        load_mug_mesh(tmp_path / "mug.dae")
    with pytest.raises(SimError, match="missing.ply.*no such file"):
        load_mug_mesh(tmp_path / "missing.ply")
    with pytest.raises(SimError, match="nowhere.*no such directory"):
        load_mug_dir(tmp_path / "nowhere")
    with pytest.raises(SimError, match="no mesh files"):
        load_mug_dir(tmp_path)
    with pytest.raises(SimError, match="up axis"):
        load_mug_mesh(tmp_path / "mug.ply", up="x")
