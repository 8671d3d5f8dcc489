"""The conventions every stage shares: one place for each fact that more than one stage relies on.

Units are SI: metres, seconds, radians inside the code (degrees only at the CLI and in reports).

Frames:
- `camera`: OpenCV axes (x right, y down, z forward), as ROS optical frames.
- `world`: one per session, metres, **z up** (gravity along -z). The core (perception, NDF,
  change detection) assumes it: the support planes are horizontal in it, the object trees cut its
  x and y, the NDF's up cue is its z. A recording whose world is not z-up is levelled before the
  core sees it (the rotation that levels it comes from the recording or from an estimate of
  gravity), so nothing downstream needs another notion of up.

Thresholds that several stages must agree on:
- `VISIBLE_PIXELS`: a view of an object is encoded (perception) and counts as the object being
  visible (scoring, the baselines, the simulator's ground truth) from this many mask pixels with
  valid depth in range; `is_visible` applies it.
- `MIN_DEPTH_M`, `MAX_DEPTH_M`: the depth range the method uses. Beyond ~4 m a mug covers a few
  hundred pixels and the depth noise of a Kinect-class sensor reaches centimetres.

Physical constants:
- `STANDARD_GRAVITY`: the magnitude of gravity an accelerometer at rest reads, for the estimate
  of up (trajectory) and the IMU readings of a bag (io).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

WORLD_UP = (0.0, 0.0, 1.0)   # the world's up direction (z): see the module docstring
HORIZONTAL_AXES = (0, 1)     # the world axes that span the ground plane (x, y)
UP_AXIS = 2                  # the world axis along WORLD_UP

# The category of an object whose NDF has no category head (NDF v2, trained on mugs alone): not
# "mug", which the model cannot tell from a bowl or a box the segmentation let through.
UNKNOWN_CATEGORY = "unknown"
# The categories whose NDF heading is a handle's, so that a turn about up shows (`ndfa.change.rotation`).
# The others are round (bowls, cups, bottles, cans) or look the same turned by half a turn (boxes).
CATEGORIES_WITH_HEADING = ("mug",)
VISIBLE_PIXELS = 300
MIN_DEPTH_M = 0.1
MAX_DEPTH_M = 4.0

STANDARD_GRAVITY = 9.80665  # m/s^2


def world_up() -> np.ndarray:
    """WORLD_UP as a fresh float64 array (3,)."""
    return np.array(WORLD_UP, dtype=np.float64)


def horizontal(points_world: np.ndarray) -> np.ndarray:
    """The ground-plane coordinates (..., 2) of world points (..., 3)."""
    return np.asarray(points_world)[..., list(HORIZONTAL_AXES)]


def depth_in_range(depth: np.ndarray, min_depth_m: float = MIN_DEPTH_M,
                   max_depth_m: float = MAX_DEPTH_M) -> npt.NDArray[np.bool_]:
    """Mask of the depth pixels the method uses: finite and within [min_depth_m, max_depth_m]."""
    in_range: npt.NDArray[np.bool_] = np.isfinite(depth) & (depth >= min_depth_m) & (depth <= max_depth_m)
    return in_range


def is_visible(n_pixels: Any) -> Any:
    """Whether a view whose mask holds `n_pixels` pixels with depth in range shows its object:
    the one rule of every visible set (the detector's observations, the evaluation's masks, a
    replayed table, the simulator's ground truth). Elementwise on arrays and on a polars
    expression, hence `Any`."""
    return n_pixels >= VISIBLE_PIXELS
