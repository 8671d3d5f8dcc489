"""The procedural categories beside the mugs (ndfa.sim.categories): closed meshes, sizes within the
ranges of the real objects they stand for and spread over them, every kind drawn, the same object
for the same seed."""

import numpy as np
import pytest
import trimesh

from ndfa.sim.bottle import BOTTLE_BODIES, BOTTLE_FINISHES, CAN_KINDS, bottle_profile, can_profile
from ndfa.sim.box import BOX_KINDS
from ndfa.sim.categories import CATEGORIES, SIZE_RANGES, make_object
from ndfa.sim.mug_body import body_profile
from ndfa.sim.vessels import BOWL_KINDS, CUP_KINDS, WALL_POINTS

NEW = [c for c in CATEGORIES if c != "mug"]
SEEDS = range(60)


def extents(obj) -> tuple[float, float, float]:
    """(widest horizontal extent, height, lowest z) of an object's mesh."""
    lo, hi = obj.mesh.bounds
    return float(max(hi[0] - lo[0], hi[1] - lo[1])), float(hi[2] - lo[2]), float(lo[2])


def crossing_segments(polygon: np.ndarray) -> list[tuple[int, int]]:
    """Pairs of non-adjacent edges of the closed polygon (P, 2) that intersect or touch."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    n = len(polygon)

    def orient(p, q, r):  # noqa: ANN001, ANN202
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    found = []
    for i in range(n):
        j = np.arange(i + 2, n if i > 0 else n - 1)  # edges sharing no vertex with edge i
        if not len(j):
            continue
        d1, d2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
        d3, d4 = orient(a[j], b[j], a[i]), orient(a[j], b[j], b[i])
        proper = (d1 * d2 < 0) & (d3 * d4 < 0)
        found += [(i, int(k)) for k in j[proper]]
    return found


def profile_of(obj) -> np.ndarray:
    if obj.category in ("bowl", "cup"):
        return body_profile(obj.params.body, WALL_POINTS)
    return bottle_profile(obj.params) if obj.category == "bottle" else can_profile(obj.params)


@pytest.mark.parametrize("category", NEW)
def test_every_part_is_a_closed_volume_standing_at_z_0(category):
    for seed in SEEDS:
        obj = make_object(category, seed)
        for part in obj.parts:
            mesh = trimesh.Trimesh(part.vertices, part.triangles, process=False)
            assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, (category, seed)
        assert extents(obj)[2] == pytest.approx(0.0, abs=1e-9), (category, seed)


@pytest.mark.parametrize("category", ["bowl", "cup", "bottle", "can"])
def test_the_revolved_profiles_never_cross_themselves(category):
    """A profile that crosses itself revolves into a surface that does (a bowl's cavity floor once
    poked through its shallow wall): the meshes are closed but not solids."""
    for seed in SEEDS:
        profile = profile_of(make_object(category, seed))
        assert profile[0, 0] == 0 and profile[-1, 0] == 0 and np.all(profile[1:-1, 0] > 0), (category, seed)
        assert not crossing_segments(profile), (category, seed, crossing_segments(profile))


def test_open3d_calls_them_watertight():
    """Open3D's test (closed, manifold, no self-intersection), as for the mugs; slow, so a few seeds,
    the lidded cups and boxes among them."""
    lidded = {"cup": next(s for s in SEEDS if make_object("cup", s).params.lid_height > 0),
              "box": next(s for s in SEEDS if make_object("box", s).params.lid_height > 0)}
    for category in NEW:
        for seed in {0, 1, lidded.get(category, 2)}:
            assert all(part.is_watertight() for part in make_object(category, seed).parts), (category, seed)


@pytest.mark.parametrize("category", CATEGORIES)
def test_sizes_stay_in_the_categorys_range_and_spread_over_it(category):
    (w_lo, w_hi), (h_lo, h_hi) = SIZE_RANGES[category]
    sizes = np.array([extents(make_object(category, seed))[:2] for seed in SEEDS])
    assert np.all((sizes[:, 0] >= w_lo) & (sizes[:, 0] <= w_hi)), (category, sizes[:, 0].min(), sizes[:, 0].max())
    assert np.all((sizes[:, 1] >= h_lo) & (sizes[:, 1] <= h_hi)), (category, sizes[:, 1].min(), sizes[:, 1].max())
    # Wide enough to matter: 60 draws cover most of each range, not a corner of it.
    assert np.ptp(sizes[:, 0]) > 0.6 * (w_hi - w_lo) and np.ptp(sizes[:, 1]) > 0.6 * (h_hi - h_lo), category


@pytest.mark.parametrize("category, attribute, kinds", [
    ("bowl", "kind", BOWL_KINDS), ("cup", "kind", CUP_KINDS), ("bottle", "body", BOTTLE_BODIES),
    ("bottle", "finish", BOTTLE_FINISHES), ("can", "kind", CAN_KINDS), ("box", "kind", BOX_KINDS),
])
def test_every_kind_is_drawn(category, attribute, kinds):
    drawn = {getattr(make_object(category, seed).params, attribute) for seed in SEEDS}
    assert drawn == set(kinds)


def test_lids_necks_and_bases_vary():
    cups = [make_object("cup", s).params for s in SEEDS]
    assert 0 < sum(c.lid_height > 0 for c in cups) < len(cups)
    assert {c.body.base_style for c in cups} == {"flat", "recessed", "foot_ring"}
    boxes = [make_object("box", s) for s in SEEDS]
    assert {len(b.parts) for b in boxes} == {1, 2}  # with and without a lid
    bottles = [make_object("bottle", s).params for s in SEEDS]
    necks = [b.neck_length for b in bottles]
    assert min(necks) < 0.02 and max(necks) > 0.06  # a water bottle's short neck, a wine bottle's long one
    assert any(b.punt > 0 for b in bottles) and any(b.punt == 0 for b in bottles)


@pytest.mark.parametrize("category", CATEGORIES)
def test_the_same_seed_gives_the_same_object(category):
    first, again, other = make_object(category, 7), make_object(category, 7), make_object(category, 8)
    assert first.params == again.params and first.model_id == again.model_id
    assert np.array_equal(first.mesh.vertices, again.mesh.vertices)
    assert np.array_equal(first.mesh.triangles, again.mesh.triangles)
    assert first.params != other.params


def test_categories_draw_independently_from_one_seed():
    """Seed 3's bowl is not seed 3's cup scaled: each category has its own stream."""
    bowl, cup = make_object("bowl", 3).params.body, make_object("cup", 3).params.body
    assert bowl.belly_height != cup.belly_height


def test_an_unknown_category_is_named():
    with pytest.raises(ValueError, match="unknown object category 'plate'"):
        make_object("plate", 0)
