"""What the reader requires of a recording's /ndfa/meta message: the format and version it can
read, and each field it or the commands use, of the right type and in range (a depth scale of NaN or
1e300 would turn every depth into nonsense and let a run end quietly with "no objects").

`meta_problem` returns the first problem as one phrase naming the field, or None.
"""

from __future__ import annotations

import math
from typing import Any

FORMAT = "ndfa.recording"
FORMAT_VERSION = 1  # the newest version this reader reads; the writer writes it

# Metres per unit of a 16UC1 depth image: from a micrometre (1e-6) to a metre (1). ndfa writes
# millimetres (0.001); TUM's PNGs are 0.0002.
DEPTH_SCALE_RANGE_M = (1e-6, 1.0)
FRAME_RATE_RANGE_HZ = (1e-3, 10_000.0)


def meta_problem(meta: Any) -> str | None:
    """The first problem of `meta` as the reader sees it, or None when it can be read."""
    if not isinstance(meta, dict):
        return f"must be a JSON object, got {type(meta).__name__}"
    if not meta:
        return "is empty: an ndfa recording's meta holds format, format_version, source, session and depth_scale"
    if meta.get("format") != FORMAT:
        return f"format must be {FORMAT!r}, got {meta.get('format')!r}: not an ndfa recording"
    version = meta.get("format_version")
    if type(version) is not int or version < 1:
        return f"format_version must be a positive integer, got {version!r}"
    if version > FORMAT_VERSION:
        return (f"format_version {version} is newer than this ndfa reads ({FORMAT_VERSION}): "
                "update ndfa, or write the recording again with this one")
    for key in ("source", "session"):
        if not isinstance(meta.get(key), str) or not meta[key]:
            return f"{key} must be a non-empty string, got {meta.get(key)!r}"
    for key, (low, high), unit in (("depth_scale", DEPTH_SCALE_RANGE_M, "metres per depth unit"),
                                   ("frame_rate_hz", FRAME_RATE_RANGE_HZ, "frames per second")):
        if key not in meta:
            continue  # depth_scale: millimetres; frame_rate_hz: not known (a sensor's own timestamps count)
        value = meta[key]
        if type(value) not in (int, float) or not math.isfinite(value) or not low <= value <= high:
            return f"{key} must be a finite number from {low:g} to {high:g} ({unit}), got {value!r}"
    if "poses" in meta and not isinstance(meta["poses"], str):
        return f"poses must be a string (\"none\": the recording has no camera poses), got {meta['poses']!r}"
    return None
