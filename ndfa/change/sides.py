"""From which sides the two sessions saw an object, and whether they share one.

The NDF's evidence about an object depends on the side a view sees: one mug's codes from opposite
sides can be as unlike as two different mugs' (0.35 on `shelves` seed 4's mug 29, 0.02-0.62 for the
kitchen's white mug), and its handle heading seen from behind the body can differ from the one seen
from the front by tens of degrees (docs/rotation.md, docs/shelves.md). A comparison of codes or
headings between the sessions is a comparison of like with like only where both sessions looked
from a common side. So each view is placed by its *azimuth*: the direction from the object to the
camera about up, in the source world (a target view's direction turned by T_rel's rotation). Two
views are from a common side when their azimuths lie within `EvidenceConfig.side_deg` of each
other; a view more than that round sees mostly what the other could not.

Pure numpy; the cameras come from the frames the detector was given (`ndfa.change.sight`'s
`SessionViews`), so a replay, which has none, knows no sides and every test here stands aside.
"""

from __future__ import annotations

import numpy as np

from ndfa.core.conventions import HORIZONTAL_AXES


def view_azimuths(cameras_world: np.ndarray, center_world: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
    """The azimuth about up (radians) of the direction from an object at `center_world` to each
    camera center of `cameras_world` (N, 3), both in one session's world; `rotation` (3, 3), when
    given, turns the directions into the source world first (T_rel's rotation for a target's views)."""
    directions = np.asarray(cameras_world, dtype=float).reshape(-1, 3) - np.asarray(center_world, dtype=float)
    if rotation is not None:
        directions = directions @ np.asarray(rotation, dtype=float).T
    x, y = HORIZONTAL_AXES
    return np.asarray(np.arctan2(directions[:, y], directions[:, x]))


def common_side(a: np.ndarray, b: np.ndarray, side_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Which azimuths of `a` lie within `side_deg` of some azimuth of `b`, and which of `b` within it
    of some of `a` (two boolean masks): the views of each session from a side the other also saw."""
    a, b = np.asarray(a, dtype=float).reshape(-1), np.asarray(b, dtype=float).reshape(-1)
    apart = np.abs((a[:, None] - b[None, :] + np.pi) % (2 * np.pi) - np.pi)
    near = apart <= np.radians(side_deg)
    return near.any(axis=1), near.any(axis=0)


def mean_azimuth_deg(azimuths: np.ndarray) -> float:
    """The circular mean of azimuths (radians), in degrees: where a session mostly looked from."""
    azimuths = np.asarray(azimuths, dtype=float)
    return float(np.degrees(np.arctan2(np.sin(azimuths).mean(), np.cos(azimuths).mean()))) if len(azimuths) else float("nan")
