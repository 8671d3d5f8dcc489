"""Generators of broken TUM RGB-D folders: the seed folder with its lists (rgb.txt, depth.txt,
groundtruth.txt, calibration.txt) edited line by line (bad numbers, missing or extra columns,
zero / NaN / huge quaternions, empty lists, garbage) and its images removed, damaged or replaced
by images of another size, bit depth or mode."""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
from hypothesis import strategies as st
from PIL import Image

LISTS = ["rgb.txt", "depth.txt", "groundtruth.txt", "calibration.txt", "ndfa_ground_truth.json"]

_NUMBERS = ["nan", "NaN", "inf", "-inf", "-1", "0", "1e400", "-1e-400", "1e19", "abc", "", "0x10", "1,5", "٣",
            "99999999999999999999", "-0", "1.000000.5"]


def bad_line(draw: st.DrawFn, line: str) -> str:
    """`line` with one of its fields replaced, removed or doubled, or a wholly different line."""
    fields = line.split()
    kind = draw(st.sampled_from(["replace", "replace", "drop", "extra", "zero quaternion", "nan quaternion",
                                 "garbage", "blank", "comment", "huge quaternion", "tab separated"]))
    if kind == "replace" and fields:
        fields[draw(st.integers(0, len(fields) - 1))] = draw(st.sampled_from(_NUMBERS))
    elif kind == "drop" and fields:
        del fields[draw(st.integers(0, len(fields) - 1))]
    elif kind == "extra":
        fields.append(draw(st.sampled_from(_NUMBERS + ["extra"])))
    elif kind in ("zero quaternion", "nan quaternion", "huge quaternion") and len(fields) >= 8:
        value = {"zero quaternion": "0", "nan quaternion": "nan", "huge quaternion": "1e300"}[kind]
        fields[4:8] = [value] * 4
    elif kind == "garbage":
        return draw(st.text(max_size=30).map(lambda t: t.replace("\n", " ")))
    elif kind == "blank":
        return ""
    elif kind == "comment":
        return "#" + line
    elif kind == "tab separated":
        return "\t".join(fields)
    return " ".join(fields)


def _png(pixels: np.ndarray) -> bytes:
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="PNG")
    return out.getvalue()


def bad_image(draw: st.DrawFn, data: bytes) -> bytes | None:
    """A replacement for an image file (None: remove it)."""
    kind = draw(st.sampled_from(["remove", "truncate", "bit flip", "empty", "8-bit", "rgb", "16-bit rgb-like",
                                 "other size", "one pixel", "float", "not a png", "jpeg"]))
    if kind == "remove":
        return None
    if kind == "truncate":
        return data[:draw(st.integers(0, max(len(data) - 1, 0)))]
    if kind == "bit flip" and data:
        flipped = bytearray(data)
        flipped[draw(st.integers(0, len(data) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(flipped)
    if kind == "empty":
        return b""
    if kind == "8-bit":
        return _png(np.full((6, 8), 200, np.uint8))
    if kind == "rgb":
        return _png(np.full((6, 8, 3), 200, np.uint8))
    if kind == "16-bit rgb-like":
        return _png(np.full((6, 8, 4), 200, np.uint8))  # RGBA
    if kind == "other size":
        return _png(np.full((draw(st.integers(1, 9)), draw(st.integers(1, 9))), 5000, np.uint16))
    if kind == "one pixel":
        return _png(np.zeros((1, 1), np.uint16))
    if kind == "float":
        out = io.BytesIO()
        Image.fromarray(np.full((6, 8), 1.5, np.float32)).save(out, format="TIFF")
        return out.getvalue()
    if kind == "jpeg":
        out = io.BytesIO()
        Image.fromarray(np.full((6, 8, 3), 100, np.uint8)).save(out, format="JPEG")
        return out.getvalue()
    return draw(st.binary(max_size=64))


@st.composite
def tum_edits(draw: st.DrawFn, seed: Path) -> list[tuple]:
    """A list of edits of the seed folder: ("list", name, new text | None) or ("image", relative
    path, new bytes | None). Drawn as data, applied by `apply_edits`, so that a failure shows them."""
    edits: list[tuple] = []
    images = sorted(str(p.relative_to(seed)) for p in seed.rglob("*.png"))
    for _ in range(draw(st.integers(1, 4))):
        target = draw(st.sampled_from(["list", "list", "list", "image"]))
        if target == "list":
            name = draw(st.sampled_from(LISTS))
            path = seed / name
            text = path.read_text() if path.exists() else ""
            kind = draw(st.sampled_from(["line", "line", "line", "remove", "empty", "comments only", "truncate",
                                         "binary", "duplicate line", "swap lines"]))
            lines = text.splitlines()
            if kind == "line" and lines:
                at = draw(st.integers(0, len(lines) - 1))
                lines[at] = bad_line(draw, lines[at])
                edits.append(("list", name, "\n".join(lines) + "\n"))
            elif kind == "remove":
                edits.append(("list", name, None))
            elif kind == "empty":
                edits.append(("list", name, ""))
            elif kind == "comments only":
                edits.append(("list", name, "".join(f"{line}\n" for line in lines if line.startswith("#"))))
            elif kind == "truncate":
                edits.append(("list", name, text[:draw(st.integers(0, len(text)))]))
            elif kind == "binary":
                edits.append(("list", name, draw(st.binary(max_size=64)).decode("latin-1")))
            elif kind == "duplicate line" and lines:
                at = draw(st.integers(0, len(lines) - 1))
                edits.append(("list", name, "\n".join(lines[:at + 1] + lines[at:]) + "\n"))
            elif kind == "swap lines" and len(lines) >= 2:
                a, b = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
                lines[a], lines[b] = lines[b], lines[a]
                edits.append(("list", name, "\n".join(lines) + "\n"))
        else:
            image = draw(st.sampled_from(images))
            edits.append(("image", image, bad_image(draw, (seed / image).read_bytes())))
    return edits


def apply_edits(seed: Path, folder: Path, edits: list[tuple]) -> Path:
    """A copy of the seed folder at `folder` with `edits` applied."""
    shutil.copytree(seed, folder)
    for _, name, content in edits:
        path = folder / name
        if content is None:
            path.unlink(missing_ok=True)
        elif isinstance(content, str):
            path.write_bytes(content.encode("utf-8", errors="surrogateescape"))
        else:
            path.write_bytes(content)
    return folder
