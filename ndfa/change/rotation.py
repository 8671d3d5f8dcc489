"""Rotated objects: a mug turned in place about up, which its center and shape code cannot show.

Each measurement carries the handle's heading about world up and how sure the NDF is of it
(`ndfa.ndf.heading`). An object fuses the headings of its reliable views (strength at least
`RotationConfig.heading_strength`) into a circular mean with its spread. A target object found
unchanged with a source partner is "rotated" when both have enough reliable views
(`RotationConfig.views`), both headings are tight (`RotationConfig.spread_deg`), and the target's heading,
brought into the source world by T_rel's rotation, differs from the partner's by more than
`RotationConfig.threshold_deg`. Otherwise nothing is said: the object stays unchanged. Mugs are close to
symmetric without their handle, so the views that cannot see it (mostly those from behind the
mug) give short handle vectors and are left out (docs/rotation.md). An object the NDF names as
a category without a handle (`CATEGORIES_WITH_HEADING`) is never "rotated": its heading is not a
handle's; nor is one whose views gave less than `RotationConfig.handle_share` of their category
probability to categories with a handle (named a mug by a bare plurality); an object of unknown
category (a model without a category head) is tested as a mug.

The heading of a view depends on the side it sees (from behind the body the handle vector can
point tens of degrees off; docs/rotation.md), and more views from one side do not average that
away, and from opposite sides the biases add. So where the detector knows its views' cameras, the
turn is measured between the views of the two sessions that saw the object from a common side
(`ndfa.change.sides`, `EvidenceConfig.side_deg`); where too few did (`RotationConfig.views` each),
the turn of all views must pass `RotationConfig.opposite_sides_factor` times the bar. A turn short
of that is doubtful: it is decided with the reason as `Rotation.withheld` and not reported
(`shelves` seed 5's mug 14, seen from the front in the source and from behind in the target: +47
deg, not turned; docs/shelves.md).

The score of a rotation is r / (1 + r) with r = |turn| / threshold_deg, at least 0.5 (a turn at
the threshold scores 0.5, 90 degrees against 30 scores 0.75; docs/scores.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ndfa.change.associate import SessionObject
from ndfa.change.config import RotationConfig
from ndfa.change.sides import common_side, mean_azimuth_deg
from ndfa.core.conventions import CATEGORIES_WITH_HEADING, HORIZONTAL_AXES, UNKNOWN_CATEGORY
from ndfa.core.events import CHANGE_SCORE


@dataclass(frozen=True)
class FusedHeading:
    """An object's heading about up from its reliable views: their circular mean weighted by
    strength (radians, its world), its circular spread (radians: sqrt(-2 ln R), R the weighted mean
    resultant length) and the views used."""

    angle_rad: float
    spread_rad: float
    views: int


@dataclass(frozen=True)
class Rotation:
    """A turn of target object O against its source partner: signed degrees about up (source
    world, counter-clockwise seen from above, source to target) and the decision's score."""

    angle_deg: float
    score: float
    target: FusedHeading
    source: FusedHeading
    margin_deg: float = 0.0  # the turn's uncertainty: `RotationConfig.margin` x the two spreads combined
    withheld: str | None = None  # why the turn is doubtful and not reported (no common side confirms it)


def fused_heading(obj: SessionObject, min_strength: float, keep: np.ndarray | None = None) -> FusedHeading | None:
    """The circular mean of `obj`'s headings with strength >= `min_strength` (of those `keep`
    marks, aligned with `obj.headings`, when given), each weighted by its strength (the mean of the
    views' horizontal handle vectors, normalised); None without any."""
    kept = [h for k, h in enumerate(obj.headings) if keep is None or keep[k]]
    views = np.array([(a, s) for a, s in kept if s >= min_strength and np.isfinite(a)]).reshape(-1, 2)
    if len(views) == 0:
        return None
    angles, weights = views[:, 0], views[:, 1] / views[:, 1].sum()
    mean = np.array([weights @ np.cos(angles), weights @ np.sin(angles)])
    length = float(np.linalg.norm(mean))
    spread = float(np.sqrt(-2.0 * np.log(length))) if length > 1e-12 else np.inf
    return FusedHeading(float(np.arctan2(mean[1], mean[0])), spread, len(angles))


def handle_share(obj: SessionObject) -> float:
    """The part of `obj`'s views' category probability that went to categories with a handle
    (`CATEGORIES_WITH_HEADING`); 1 when none was named (a model without a category head: a mug)."""
    total = sum(obj.category_votes.values())
    if total <= 0:
        return 1.0
    return sum(v for name, v in obj.category_votes.items() if name in CATEGORIES_WITH_HEADING) / total


def source_heading(angle_rad: float, rotation: np.ndarray) -> float:
    """A target-world heading in the source world: its direction rotated by T_rel's rotation and
    taken about up again (T_rel is a yaw with at most a small tilt)."""
    direction = np.zeros(3)
    x, y = HORIZONTAL_AXES
    direction[x], direction[y] = np.cos(angle_rad), np.sin(angle_rad)
    turned = rotation @ direction
    return float(np.arctan2(turned[y], turned[x]))


def rotation_of(target: SessionObject, partner: SessionObject, rotation: np.ndarray,
                config: RotationConfig, sides: tuple[np.ndarray, np.ndarray] | None = None,
                side_deg: float | None = None) -> Rotation | None:
    """O's turn against its unchanged partner when it is a rotation, else None (the test is off, an
    object has no handle, a heading lacks reliable views or is too spread, or the turn is under the
    bar). `sides`: the azimuths (source world, `ndfa.change.sides`) of the views of `target.headings`
    and `partner.headings`; with `side_deg`, the turn is measured between the views from a common
    side; where there are too few of them, the turn of all views must pass the bar
    `config.opposite_sides_factor` times over, and a turn all the views show that the views from a
    common side do not is returned `withheld` with the reason."""
    if config.threshold_deg is None:
        return None
    if any(o.category not in (*CATEGORIES_WITH_HEADING, UNKNOWN_CATEGORY) or handle_share(o) < config.handle_share
           for o in (target, partner)):
        return None
    if sides is None or side_deg is None:
        return _turn(target, partner, rotation, config)
    target_sides, partner_sides = common_side(sides[0], sides[1], side_deg)
    common = _turn(target, partner, rotation, config, (target_sides, partner_sides))
    if common is not None:
        return common
    turned = _turn(target, partner, rotation, config)
    if turned is None:
        return None
    counts = [int(sum(1 for (a, s), k in zip(o.headings, keep) if k and s >= config.heading_strength and np.isfinite(a)))
              for o, keep in ((target, target_sides), (partner, partner_sides))]
    seen = (f"the target seen from {mean_azimuth_deg(sides[0]):+.0f} deg, the source from "
            f"{mean_azimuth_deg(sides[1]):+.0f} deg")
    if min(counts) >= config.views:  # the views from a common side show no such turn
        why = (f"turned {turned.angle_deg:+.0f} deg by the headings of all views ({seen}), but not by the "
               f"{counts[0]} target and {counts[1]} source reliable views from a common side")
        return replace(turned, withheld=why)
    assert config.threshold_deg is not None  # `_turn` found a turn
    bar = config.opposite_sides_factor * config.threshold_deg
    if abs(turned.angle_deg) - turned.margin_deg > bar:
        return turned  # past the bar of views from opposite sides, whose biases add
    why = (f"turned {turned.angle_deg:+.0f} deg (less {turned.margin_deg:.0f} of spread) by views from opposite sides "
           f"only ({seen}; {counts[0]} / {counts[1]} reliable views from a common side), under the {bar:.0f} deg "
           f"such views need: a heading's bias reverses with the side it is seen from")
    return replace(turned, withheld=why)


def _turn(target: SessionObject, partner: SessionObject, rotation: np.ndarray, config: RotationConfig,
          keep: tuple[np.ndarray, np.ndarray] | None = None) -> Rotation | None:
    """The turn of `rotation_of` from the views `keep` marks (all: None), or None."""
    assert config.threshold_deg is not None  # the caller checked the test is on
    headings = [fused_heading(o, config.heading_strength, None if keep is None else keep[k])
                for k, o in enumerate((target, partner))]
    spread = np.radians(config.spread_deg)
    if any(h is None or h.views < config.views or h.spread_rad > spread for h in headings):
        return None
    target_heading, partner_heading = headings
    assert target_heading is not None and partner_heading is not None  # refused above
    turn = (source_heading(target_heading.angle_rad, rotation) - partner_heading.angle_rad + np.pi) % (2 * np.pi) - np.pi
    angle_deg = float(np.degrees(turn))
    # The turn less its uncertainty must pass the bar: a view-dependent bias of the headings is not
    # averaged away by more views of the same side, so the spreads themselves are the margin.
    margin = config.margin * float(np.degrees(np.hypot(target_heading.spread_rad, partner_heading.spread_rad)))
    if abs(angle_deg) - margin <= config.threshold_deg:
        return None
    ratio = (abs(angle_deg) - margin) / config.threshold_deg
    return Rotation(angle_deg, max(ratio / (1.0 + ratio), CHANGE_SCORE), target_heading, partner_heading, margin)
