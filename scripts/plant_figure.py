"""One frame of a recording beside the same frame planted (`ndfa plant`): colour above, depth below.

    python scripts/plant_figure.py ORIGINAL.mcap PLANTED.mcap POSITION OUT.png [SCALE]

POSITION counts frames from 0 in both recordings; SCALE (default 0.5) shrinks the images. The PNG
is palette-quantised to keep it small (docs/plant.png).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image

from ndfa.io.recording import RecordingReader

MAX_DEPTH_M = 4.0  # depth shown from black (0 m) to white (4 m); no depth is black too


def frame_at(path: Path, position: int):
    return next(RecordingReader(path).frames(start=position, stop=position + 1))


def depth_image(depth: np.ndarray) -> np.ndarray:
    grey = (np.clip(depth / MAX_DEPTH_M, 0.0, 1.0) * 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


def main(original: Path, planted: Path, position: int, out: Path, scale: float = 0.5) -> None:
    before, after = frame_at(original, position), frame_at(planted, position)
    rows = [np.concatenate([before.rgb, after.rgb], axis=1),
            np.concatenate([depth_image(before.depth), depth_image(after.depth)], axis=1)]
    image = Image.fromarray(np.concatenate(rows, axis=0))
    image = image.resize((round(image.width * scale), round(image.height * scale)), Image.LANCZOS)
    image.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)
    print(f"{out}: {out.stat().st_size // 1024} KB")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4]),
         float(sys.argv[5]) if len(sys.argv) > 5 else 0.5)
