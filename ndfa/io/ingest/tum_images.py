"""Decoding the PNGs of a TUM RGB-D folder: 16-bit depth, 8-bit colour, 8- or 16-bit instance masks.

Every problem (unreadable file, wrong bit depth, size mismatch) is an IngestError naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from ndfa.core.errors import IngestError

# The largest 16-bit value: Kinect-class sensors and datasets built on them (7-Scenes) write it for
# "no reading", as others write 0. Read as a distance it would be 65.5 m (at 1000 units per metre):
# a wall that is not there for anything that does not clip depth to the method's range.
NO_READING = np.iinfo(np.uint16).max


def read_depth(path: Path, depth_scale: float) -> np.ndarray:
    """(H, W) float32 metres, 0 = invalid (both 0 and 65535 in the PNG mark a pixel without a
    reading); the PNG holds `depth_scale` units per metre."""
    pixels = _read_16bit(path, "a depth image")
    depth = (pixels.astype(np.float64) / depth_scale).astype(np.float32)
    depth[pixels == NO_READING] = 0.0
    return depth


def read_mask(path: Path) -> np.ndarray:
    """(H, W) uint16 instance ids; 8-bit masks are widened (ids < 256 fit)."""
    image = _read_png(path)
    if image.mode == "L":
        return np.array(image).astype(np.uint16)
    return _read_16bit(path, "an instance mask")


def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8."""
    image = _read_png(path)
    if image.mode not in ("RGB", "RGBA", "L", "P"):
        raise IngestError(f"{path}: a colour image must be an 8-bit RGB PNG, but it has mode {image.mode}")
    return np.array(image.convert("RGB"))


def check_size(path: Path, shape: tuple[int, ...], depth_path: Path, depth_shape: tuple[int, ...]) -> None:
    """An IngestError unless the image at `path` has its depth image's size."""
    if tuple(shape) != tuple(depth_shape):
        raise IngestError(f"{path} is {shape[1]}x{shape[0]} pixels but its depth image {depth_path} is "
                          f"{depth_shape[1]}x{depth_shape[0]}")


def _read_png(path: Path) -> Image.Image:
    """The decoded image, its file closed (a failed decode must not leave the file open either)."""
    try:
        with Image.open(path) as image:
            image.load()
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as error:
        raise IngestError(f"{path} is not a readable image: {error}") from error
    return image


def _read_16bit(path: Path, what: str) -> np.ndarray:
    image = _read_png(path)
    if image.mode not in ("I;16", "I;16B", "I;16L", "I"):
        bits = {"1": "1-bit", "L": "8-bit", "P": "8-bit palette", "RGB": "8-bit RGB", "RGBA": "8-bit RGBA"}
        raise IngestError(f"{path}: {what} must be a 16-bit single-channel PNG, but it is "
                          f"{bits.get(image.mode, 'mode ' + image.mode)}")
    pixels = np.array(image)
    if pixels.dtype != np.uint16:
        if pixels.min(initial=0) < 0 or pixels.max(initial=0) > np.iinfo(np.uint16).max:
            raise IngestError(f"{path}: {what} values do not fit 16 bits")
        pixels = pixels.astype(np.uint16)
    return pixels
