"""Which way a mug's handle points about world up, read from one observation's latent z.

The "frame" decoder (`ndfa.ndf.decoder.OccupancyDecoder.frame`) is a VN-linear map of z to two
vectors, and training aligned them with the mug's axis and its handle direction
(`ndfa.training.losses.frame_loss`). A VN-linear map is a fixed linear combination of z's
vectors, so with z in the world frame (`ObjectCode.z`) the handle vector is `W[1] @ z` in the
world too: numpy, no extra network run, the same for every runtime.

Its length says how sure the network is. Where the handle cannot be seen (behind the body) the
frame loss could only average over the mugs' possible handle directions, so the network learnt
to shrink the vector there instead of guessing: on the source sessions of the seven baseline
scenes the views whose horizontal handle vector is long have a heading within a few degrees of
the truth, the short ones are often far off (docs/rotation.md). `Heading.strength` is that
length; the detector fuses only the views strong enough (`DecisionConfig.heading_strength`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.conventions import HORIZONTAL_AXES, world_up

HANDLE_VECTOR = 1  # the frame decoder's second vector is trained onto the handle (the first: the axis)


@dataclass(frozen=True)
class Heading:
    """The handle's azimuth about world up in the world frame (radians, from world x towards y)
    and the horizontal length of the network's handle vector (z's scaled units; 0: no heading)."""

    angle_rad: float = float("nan")
    strength: float = 0.0


def handle_heading(z_world: np.ndarray, frame_weights: np.ndarray | None) -> Heading:
    """The heading of one observation from its z `[k, 3]` (world frame) and the frame decoder's
    weights `[2, k]` (`frame_weights`); None (a model without the frame decoder): no heading."""
    if frame_weights is None:
        return Heading()
    handle = np.asarray(frame_weights, dtype=np.float64)[HANDLE_VECTOR] @ np.asarray(z_world, dtype=np.float64)
    up = world_up()
    flat = handle - (handle @ up) * up  # the part about up: a handle tilted up or down still points somewhere
    x, y = (float(flat[axis]) for axis in HORIZONTAL_AXES)
    return Heading(float(np.arctan2(y, x)), float(np.hypot(x, y)))


def frame_weights_of(model: object) -> np.ndarray | None:
    """The frame decoder's VN-linear weights `[2, k]` of an `NDFModel`, or None when its decoder
    builds no trained frame (the "dots" decoder)."""
    decoder = getattr(model, "decoder", None)
    if decoder is None or not getattr(decoder, "use_frame", False):
        return None
    weights: np.ndarray = decoder.frame.linear.weight.detach().cpu().numpy().astype(np.float64)
    return weights

