"""Pixels of ROS image messages: decode sensor_msgs/Image and sensor_msgs/CompressedImage into numpy
arrays, and encode them back (for `ndfa export bag`).

Kept apart from the bag logic because it is pure bytes-to-pixels work: no topics, no time. Every
decoder raises `ImageDecodeError` (a ValueError) on data it cannot read; `UnknownEncodingError`
is separate, because an unknown encoding is a problem of the whole topic (the importer stops and
names it), while a corrupt message is one lost frame (the importer skips it and counts it).

Encodings follow sensor_msgs/image_encodings: depth as 16UC1 (= mono16, millimetres) or 32FC1
(metres); colour as rgb8, bgr8, rgba8, bgra8 or mono8; instance masks as 16UC1/mono16 (or 8-bit).
The `compressedDepth` format of compressed_depth_image_transport is a 12-byte header (int32
compression format, two float32 depth quantisation parameters) followed by a PNG: 16-bit
millimetres for 16UC1, quantised inverse depth (depth = a / (value - b)) for 32FC1.
"""

from __future__ import annotations

import io
import struct

import numpy as np
from PIL import Image as PILImage

COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8UC1", "8UC3")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
MASK_ENCODINGS = ("16UC1", "mono16", "8UC1", "mono8")

COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")  # format (0 = PNG), depthQuantA, depthQuantB
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class ImageDecodeError(ValueError):
    """One message's pixels cannot be decoded (truncated data, a corrupt PNG or JPEG)."""


class UnknownEncodingError(ValueError):
    """An image encoding (or compressed format) ndfa cannot turn into the role's pixels."""


def image_pixels(message: object) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as an (H, W) or (H, W, C) array of the encoding's dtype."""
    encoding = message.encoding
    dtype, channels = _raw_layout(encoding)
    height, width, step = int(message.height), int(message.width), int(message.step)
    if message.is_bigendian and dtype.itemsize > 1:
        dtype = dtype.newbyteorder(">")
    row_bytes = width * channels * dtype.itemsize
    data = np.asarray(message.data, dtype=np.uint8)
    if height == 0 or width == 0 or step < row_bytes or data.size < step * (height - 1) + row_bytes:
        raise ImageDecodeError(f"{data.size} bytes do not hold a {width}x{height} {encoding} image (step {step})")
    data = np.pad(data, (0, step * height - data.size)) if data.size < step * height else data[: step * height]
    rows = data.reshape(height, step)[:, :row_bytes]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape((height, width, channels) if channels > 1 else (height, width))
    return pixels.astype(dtype.newbyteorder("="), copy=False)


def _raw_layout(encoding: str) -> tuple[np.dtype, int]:
    layouts = {
        "rgb8": ("u1", 3), "bgr8": ("u1", 3), "8UC3": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4),
        "mono8": ("u1", 1), "8UC1": ("u1", 1), "mono16": ("<u2", 1), "16UC1": ("<u2", 1), "32FC1": ("<f4", 1),
    }
    if encoding not in layouts:
        raise UnknownEncodingError(f"encoding {encoding!r}")
    dtype, channels = layouts[encoding]
    return np.dtype(dtype), channels


def color_from_image(message: object) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour sensor_msgs/Image."""
    if message.encoding not in COLOR_ENCODINGS:
        raise UnknownEncodingError(f"encoding {message.encoding!r} is not a colour encoding {COLOR_ENCODINGS}")
    pixels = image_pixels(message)
    if pixels.ndim == 2:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    if message.encoding.startswith("bgr"):
        pixels = pixels[:, :, 2::-1]
    return np.ascontiguousarray(pixels[:, :, :3])


def depth_from_image(message: object) -> np.ndarray:
    """(H, W) float32 depth in metres (0 = invalid) of a 16UC1/mono16 (mm) or 32FC1 (m) sensor_msgs/Image."""
    if message.encoding not in DEPTH_ENCODINGS:
        raise UnknownEncodingError(f"encoding {message.encoding!r} is not a depth encoding {DEPTH_ENCODINGS}")
    return _depth_in_metres(image_pixels(message))


def mask_from_image(message: object) -> np.ndarray:
    """(H, W) uint16 instance ids of a 16UC1/mono16 (or 8-bit) sensor_msgs/Image."""
    if message.encoding not in MASK_ENCODINGS:
        raise UnknownEncodingError(f"encoding {message.encoding!r} is not a mask encoding {MASK_ENCODINGS}")
    return image_pixels(message).astype(np.uint16)


def color_from_compressed(message: object) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a JPEG or PNG sensor_msgs/CompressedImage."""
    if "compresseddepth" in message.format.lower():
        raise UnknownEncodingError(f"format {message.format!r} is depth, not colour")
    image = _open_image(message.data)
    return np.asarray(image.convert("RGB"))


def depth_from_compressed(message: object) -> np.ndarray:
    """(H, W) float32 depth in metres of a `compressedDepth` (or 16-bit PNG) sensor_msgs/CompressedImage."""
    fmt = message.format
    data = bytes(message.data)
    quantization = (0.0, 0.0)
    if "compresseddepth" in fmt.lower() and not data.startswith(_PNG_MAGIC):
        if len(data) < COMPRESSED_DEPTH_HEADER.size:
            raise ImageDecodeError(f"{len(data)} bytes are too short for a compressedDepth header")
        _, quant_a, quant_b = COMPRESSED_DEPTH_HEADER.unpack_from(data)
        quantization, data = (quant_a, quant_b), data[COMPRESSED_DEPTH_HEADER.size:]
    if not data.startswith(_PNG_MAGIC):
        raise UnknownEncodingError(f"format {fmt!r}: compressed depth must be PNG")
    values = np.asarray(_open_image(data))
    if values.ndim != 2:
        raise ImageDecodeError(f"the depth PNG has {values.shape[2]} channels, expected 1")
    if fmt.split(";")[0].strip() == "32FC1":
        # Inverse depth, quantised: value = a / depth + b; 0 marks an invalid pixel.
        quant_a, quant_b = quantization
        valid = values > 0
        depth = np.zeros(values.shape, np.float32)
        depth[valid] = quant_a / (values[valid].astype(np.float32) - quant_b)
        return depth
    return _depth_in_metres(values.astype(np.uint16))


def _depth_in_metres(pixels: np.ndarray) -> np.ndarray:
    if pixels.dtype == np.uint16:
        return pixels.astype(np.float32) * np.float32(0.001)
    depth = np.nan_to_num(pixels.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    depth[depth < 0] = 0.0
    return depth


def _open_image(data: object) -> PILImage.Image:
    try:
        image = PILImage.open(io.BytesIO(bytes(data)))
        image.load()
    except (OSError, SyntaxError, ValueError) as error:  # PIL's errors for corrupt and truncated files
        raise ImageDecodeError(f"cannot decode the compressed image: {error}") from None
    return image


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 or (H, W) uint16 array (lossless)."""
    buffer = io.BytesIO()
    PILImage.fromarray(pixels).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def encode_jpeg(rgb: np.ndarray, quality: int = 95) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 RGB image (lossy)."""
    buffer = io.BytesIO()
    PILImage.fromarray(rgb).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def encode_compressed_depth(depth_mm: np.ndarray) -> bytes:
    """compressedDepth bytes of (H, W) uint16 millimetres: the 12-byte header, then a 16-bit PNG."""
    return COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0) + encode_png(depth_mm)


def mask_from_compressed(message: object) -> np.ndarray:
    """(H, W) uint16 instance ids of a PNG sensor_msgs/CompressedImage (8- or 16-bit, one channel)."""
    values = np.asarray(_open_image(message.data))
    if values.ndim != 2:
        raise ImageDecodeError(f"the mask PNG has {values.shape[2]} channels, expected 1")
    return values.astype(np.uint16)
