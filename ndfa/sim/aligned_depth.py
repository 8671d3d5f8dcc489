"""Depth aligned to colour as a RealSense D400 writes it (`align_to=color`).

An active-stereo camera measures depth in its left imager; the background just to the left of a
foreground edge is seen by the left imager but hidden from the right one, so it gets no depth: a
band `f * B * (1/z_near - 1/z_far)` pixels wide (B: the stereo baseline, 50 mm on a D435).
Aligning that depth to the colour camera, a little to the side (about 15 mm), re-projects every
point; background that the depth imager could not see from its own position, beside the other
side of foreground edges, is left empty (a narrower band). The simulator renders from the colour
camera, so both bands are cut into its depth here. (The depth is already in the colour camera's
pixels and intrinsics, as an aligned stream is.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_BAND_PX = 40  # wider bands (a hand in front of a far wall) are cut at this width


@dataclass(frozen=True)
class AlignedDepth:
    """stereo_baseline_m: between the two imagers (the band left of foreground edges);
    colour_offset_m: between the depth imager and the colour camera (the band on the right)."""

    stereo_baseline_m: float = 0.050
    colour_offset_m: float = 0.015

    def apply(self, depth: np.ndarray, fx: float) -> np.ndarray:
        """`depth` (metres, 0 = none) with both bands cut out."""
        depth = np.asarray(depth)
        inverse = np.where(depth > 0, 1.0 / np.where(depth > 0, depth, 1.0), 0.0)
        hidden = _band(inverse, fx * self.stereo_baseline_m, left=True) | _band(inverse, fx * self.colour_offset_m, left=False)
        return np.where(hidden, 0.0, depth).astype(depth.dtype)


def _band(inverse: np.ndarray, pixels_per_inverse_m: float, left: bool) -> np.ndarray:
    """Pixels with depth that a nearer pixel s columns to their right (left=True) or left hides:
    (1/z_near - 1/z) * pixels_per_inverse_m >= s."""
    hidden = np.zeros(inverse.shape, dtype=bool)
    valid = inverse > 0
    for shift in range(1, MAX_BAND_PX + 1):
        if left:
            near, here = inverse[:, shift:], inverse[:, :-shift]
            target = hidden[:, :-shift]
            ok = valid[:, :-shift]
        else:
            near, here = inverse[:, :-shift], inverse[:, shift:]
            target = hidden[:, shift:]
            ok = valid[:, shift:]
        covered = ok & (near > 0) & ((near - here) * pixels_per_inverse_m >= shift)
        if not covered.any() and shift > 2:
            band_possible = (near - here).max(initial=0.0) * pixels_per_inverse_m >= shift
            if not band_possible:
                break
        target |= covered
    return hidden
