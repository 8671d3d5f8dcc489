"""Is a mug named a cup or a can because its handle is out of view? (issue 33's per-view category bar)

NDF v3 names 0.666 of the mugs' regime views "mug" (the model card's `ndf-eval` table): a third go
to cup or can. A mug whose handle the view does not show has a cup's or a can's shape, so no
model can name it from that view. This study renders the `ndf-eval` test views of the mugs (the
same seed, split and view generator), counts for each view the depth points that lie on the mug's
handle (within `ON_PART_M` of the handle's surface and farther than that from the body's: the
handle's roots touch the body), and gives the category accuracy with the handle in view and out
of it, in the detector's regime (`ndfa.training.ndf_eval`'s `detector_regime`).

    .venv/bin/python studies/mug_handle_views.py ndfa/ndf/weights/ndf_objects.pt [MUGS] [VIEWS_PER_MUG] [MIN_HANDLE_POINTS]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ndfa.core.geometry import invert_pose, transform_points
from ndfa.sim.mesh import Mesh
from ndfa.sim.splits import make_split_object
from ndfa.training.dataset import generate_views
from ndfa.training.ndf_eval import evaluate_ndf
from ndfa.training.views import ViewConfig

ON_PART_M = 0.004  # a depth point this close to a part's surface is on it (the views' noise is ~1-3 mm within 2 m)
SURFACE_SAMPLES = 20_000  # points sampled on each part's surface


def surface_samples(mesh: Mesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` points uniform over the mesh's surface (area-weighted triangles, uniform barycentrics)."""
    corners = mesh.vertices[mesh.triangles]                     # (F, 3, 3)
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    picked = rng.choice(len(areas), count, p=areas / areas.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    a, b, c = corners[picked, 0], corners[picked, 1], corners[picked, 2]
    return a + u[:, None] * (b - a) + v[:, None] * (c - a)


def handle_points(views: dict[str, np.ndarray]) -> np.ndarray:
    """(V,) the share of each view's points that lie on its mug's handle (0 for a mug without one)."""
    rng = np.random.default_rng(0)
    trees: dict[int, tuple[cKDTree, cKDTree] | None] = {}
    shares = np.zeros(len(views["points"]))
    for row, (points, pose, index) in enumerate(zip(views["points"], views["pose_camera_object"], views["object_index"])):
        index = int(index)
        if index not in trees:
            mug = make_split_object("mug", "test", index)
            trees[index] = None if len(mug.parts) < 2 else (
                cKDTree(surface_samples(mug.parts[0], SURFACE_SAMPLES, rng)),
                cKDTree(surface_samples(mug.parts[1], SURFACE_SAMPLES, rng)))
        if trees[index] is None:
            continue
        body, handle = trees[index]
        in_object = transform_points(invert_pose(pose.astype(np.float64)), points.astype(np.float64))
        near_handle = handle.query(in_object, distance_upper_bound=ON_PART_M)[0] < np.inf
        near_body = body.query(in_object, distance_upper_bound=ON_PART_M)[0] < np.inf
        shares[row] = float(np.mean(near_handle & ~near_body))
    return shares


def main(weights: Path, mugs: int = 20, views_per_mug: int = 50, min_share: float = 0.02) -> None:
    views = generate_views("test", list(range(mugs)), views_per_mug, 0, ViewConfig(), categories=("mug",))
    _, table = evaluate_ndf(weights, mugs=mugs, views_per_mug=views_per_mug, iou_grid=0, views=views,
                            categories=("mug",))
    share = handle_points(views)
    regime = table["detector_regime"].to_numpy()
    named = table["predicted_category"].to_numpy()
    print(f"{weights}: {mugs} test mugs x {views_per_mug} views, {int(regime.sum())} in the regime")
    for bar in sorted({min_share, 0.005, 0.01, 0.05}):
        shown = share >= bar
        print(f"handle in view: >= {bar:.1%} of the view's points on it (within {ON_PART_M * 1e3:.0f} mm)")
        for label, rows in (("all regime views", regime), ("handle in view", regime & shown),
                            ("handle out of view", regime & ~shown)):
            counts = {c: int(np.sum(named[rows] == c)) for c in np.unique(named[rows])}
            accuracy = float(np.mean(named[rows] == "mug")) if rows.any() else float("nan")
            print(f"  {label:20s} {int(rows.sum()):4d} views  named mug {accuracy:.3f}  {counts}")


if __name__ == "__main__":
    arguments = sys.argv[1:]
    if not arguments:
        raise SystemExit(__doc__)
    main(Path(arguments[0]), *(int(a) for a in arguments[1:3]), *(float(a) for a in arguments[3:4]))
