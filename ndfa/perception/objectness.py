"""Is a cluster above a support plane a mug? Its shape measured in the plane's frame, and a gate.

The clusters of `ndfa.perception.segmentation` are whatever sticks out of a horizontal plane:
on a real table that is mostly not mugs (magazines and papers lying flat, the edge of a counter
or a shelf seen at the right height, chair backs, slats), and every one that passes becomes an
object the detector tracks and may report. The gate keeps clusters of a mug's scale and build:

- tall enough and not too tall (`min_top_m`..`max_top_m`): a magazine is flat, a chair back tall;
- standing on the plane (`max_bottom_m`): its lowest points touch the support;
- a mug's footprint (`min_length_m`..`max_length_m`, `min_width_m`): a counter edge or a row of
  brochures is long, a bottle or a tap narrow; a single view of a mug sees about half of it,
  which is still a few cm deep;
- not a column (`max_aspect`): a mug is at most about twice as tall as it is wide;
- compact (`min_width_ratio`): not a sliver (the edge of a board seen end-on).

The footprint is measured along the principal axes of the cluster's horizontal positions, as a
percentile range (`FOOTPRINT_PERCENTILES`) so that a few stray points do not stretch it. Figures
from which the defaults were chosen are in docs/segmentation.md. Pure numpy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FOOTPRINT_PERCENTILES = (2.0, 98.0)


@dataclass(frozen=True)
class ObjectnessConfig:
    """Which clusters count as objects (mugs). Lengths in metres; heights above the support plane.

    The synthetic mugs are 6-13 cm tall and 7-12 cm across with the handle
    (`ndfa.sim.mug_params`); the real ones in 7-Scenes redkitchen ~9-10 cm tall and 8-11 cm across.

    min_top_m, max_top_m: the cluster's top (95th percentile of height) must lie in this range:
        below, a flat thing (magazines, a controller, a table's noise); above, a tall one
        (chair backs, bottles, a wall's foot).
    max_bottom_m: its bottom (5th percentile of height) must be at most this: a mug stands on
        the plane, so its lowest sampled points lie within the first centimetres above it
        (the candidates start at `SegmentationConfig.min_height_m`).
    min_length_m, max_length_m: the footprint's longer side (see `FOOTPRINT_PERCENTILES`) lies in
        this range: a mug's diameter at least, and at most a mug with its handle plus depth noise;
        counter edges, rows of brochures and a game controller are longer, taps and bottles
        narrower.
    min_width_m: the footprint's shorter side at least this: one view sees the front half of a
        mug's body, a few cm deep; the edge of a board or a chair's slat is a sliver.
    min_width_ratio: shorter over longer side at least this (compact, not a strip).
    max_aspect: top over the longer side at most this (the `paper` scene's mug views reach 2.1).
    """

    min_top_m: float = 0.05
    max_top_m: float = 0.15
    max_bottom_m: float = 0.05
    min_length_m: float = 0.045
    max_length_m: float = 0.13
    min_width_m: float = 0.02
    min_width_ratio: float = 0.2
    max_aspect: float = 2.2

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_top_m < self.max_top_m:
            raise ValueError("need 0 <= min_top_m < max_top_m")
        if not 0.0 <= self.min_width_m < self.max_length_m:
            raise ValueError("need 0 <= min_width_m < max_length_m")
        if not self.min_length_m < self.max_length_m:
            raise ValueError("need min_length_m < max_length_m")


@dataclass(frozen=True)
class ClusterShape:
    """A cluster's shape relative to its support plane (metres).

    points: sampled points in the cluster. bottom_m, top_m: 5th and 95th percentile of height
    above the plane. length_m >= width_m: the footprint's extents along its principal axes.
    depth_m: median depth from the camera (how noisy the figures are).
    """

    points: int
    bottom_m: float
    top_m: float
    length_m: float
    width_m: float
    depth_m: float


def cluster_shape(heights: np.ndarray, flat: np.ndarray, depths: np.ndarray) -> ClusterShape:
    """The shape of a cluster from its points' heights above the plane (N,), horizontal
    coordinates in the plane (N, 2) and depths from the camera (N,)."""
    bottom, top = np.percentile(heights, [5, 95])
    length, width = footprint(flat)
    return ClusterShape(points=len(heights), bottom_m=float(bottom), top_m=float(top), length_m=length,
                        width_m=width, depth_m=float(np.median(depths)))


def footprint(flat: np.ndarray) -> tuple[float, float]:
    """(longer, shorter) extent of 2-D points along their principal axes, as a percentile range."""
    centred = flat - flat.mean(axis=0)
    if len(flat) < 3:
        extents = np.ptp(centred, axis=0) if len(flat) else np.zeros(2)
        return float(extents.max()), float(extents.min())
    _, vectors = np.linalg.eigh(centred.T @ centred)
    along = centred @ vectors  # columns: minor axis, major axis
    low, high = np.percentile(along, FOOTPRINT_PERCENTILES, axis=0)
    width, length = (high - low).tolist()
    return float(length), float(width)


def rejection(shape: ClusterShape, config: ObjectnessConfig = ObjectnessConfig()) -> str | None:
    """Why the cluster is not a mug ("flat", "tall", "floating", "long", "short", "thin", "sliver",
    "column"), or None."""
    if shape.top_m < config.min_top_m:
        return "flat"
    if shape.top_m > config.max_top_m:
        return "tall"
    if shape.bottom_m > config.max_bottom_m:
        return "floating"
    if shape.length_m > config.max_length_m:
        return "long"
    if shape.length_m < config.min_length_m:
        return "short"
    if shape.width_m < config.min_width_m:
        return "thin"
    if shape.width_m < config.min_width_ratio * shape.length_m:
        return "sliver"
    if shape.top_m > config.max_aspect * shape.length_m:
        return "column"
    return None
