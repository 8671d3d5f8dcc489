"""`ndfa segment`: a copy of a recording whose instance channel is the geometric segmentation.

The I/O shell around `ndfa.perception.segmentation`: read every frame, segment it, write it.
With `relabel` (evaluation only: `ndfa.eval.segmentation.relabel_to_truth`, which `ndfa segment
--keep-truth` passes) and a recording with ground-truth masks, each segment is relabelled with the
ground-truth instance it overlaps, so that `ndfa detect` on the copy can be scored: the detector
names an object by the first mask id it was built from, and never uses ids otherwise.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from ndfa.core.conventions import depth_in_range
from ndfa.core.errors import RecordingError
from ndfa.core.progress import Progress
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.perception.segmentation import segment_frame
from ndfa.perception.segmentation_config import SegmentationConfig

# (segment labels, ground-truth instances, pixels with depth) -> the labels to write
Relabel = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
_WRITER_META_KEYS = ("format", "format_version", "depth_scale", "units")


def segment_recording(source: Path, out: Path, config: SegmentationConfig = SegmentationConfig(),
                      relabel: Relabel | None = None, on_frame: Progress | None = None) -> int:
    """Write `out`: `source` with every frame's instances replaced by its segmentation (relabelled by
    `relabel` against the recording's masks, when it has them). Returns frames written."""
    reader = RecordingReader(source)
    if Path(out).resolve() == Path(source).resolve():
        raise RecordingError(f"{out}: the output must not be the input recording")
    relabel = relabel if reader.has_instances else None
    meta = {k: v for k, v in reader.meta.items() if k not in _WRITER_META_KEYS}
    meta["segmentation"] = {"config": {k: list(v) if isinstance(v, tuple) else v
                                       for k, v in dataclasses.asdict(config).items()},
                            "from": str(source), "ids": "ground truth where IoU >= 0.5" if relabel is not None else "segment labels"}
    total = len(reader)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    count = 0
    with RecordingWriter(out, meta) as writer:
        for frame in reader.frames():
            labels = segment_frame(frame, config)
            if relabel is not None and frame.instances is not None:
                valid = depth_in_range(frame.depth, config.min_depth_m, config.max_depth_m)
                labels = relabel(labels, frame.instances, valid)
            writer.write_frame(dataclasses.replace(frame, instances=labels))
            count += 1
            if on_frame is not None:
                on_frame(count, total)
        if reader.ground_truth is not None:
            writer.write_ground_truth(reader.ground_truth)
    return count
