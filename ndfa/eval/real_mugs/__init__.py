"""The real-mug protocol of `ndfa ndf-eval --real DIR` (issue 17, item 4): the NDF on the mugs of a
real RGB-D sequence with given poses, against the visible points' centroid. docs/real_mugs.md.

    source.py    the sequence (TUM folder or ndfa recording) with its poses, levelled to z-up
    tracks.py    the mugs: the detector's segmentation on raw frames, tracked by world position
    protocol.py  the NDF on each view, and the figures: spreads over views >= 45 degrees apart,
                 code similarity of same-mug and cross-mug pairs
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ndfa.core.frame import Frame
from ndfa.core.progress import Progress
from ndfa.eval.real_mugs.protocol import ProtocolConfig, encode_views, measure
from ndfa.eval.real_mugs.source import RealSequence, open_sequence
from ndfa.eval.real_mugs.tracks import MugTracks, TrackConfig, find_mugs, require_mugs
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder

MIN_MUGS = 2  # the code similarity compares two mugs; one found is a failure to explain, not a result


@dataclass
class RealMugResult:
    """What the protocol measured for each set of weights ("weights" column: the path or "shipped").

    summary: one row per mug and a row "all" (see `protocol.measure`); views: one row per view;
    windows: one row per window of views (`protocol.time_windows`)."""

    sequence: RealSequence
    tracks: MugTracks
    summary: pl.DataFrame
    views: pl.DataFrame
    windows: pl.DataFrame


def evaluate_real_mugs(path: Path, weights: list[Path | None], frame_step: int = 1,
                       tracks: TrackConfig = TrackConfig(), protocol: ProtocolConfig = ProtocolConfig(),
                       on_progress: Progress | None = None) -> RealMugResult:
    """Open `path`, find its mugs in every `frame_step`-th frame (once), and measure each of
    `weights` (None: the shipped ones) on the same views. `on_progress(frames done, frames to look at)`."""
    if frame_step < 1:
        raise ValueError(f"frame_step must be >= 1, got {frame_step}")
    sequence = open_sequence(path)
    total = -(-sequence.frame_count // frame_step)

    def frames() -> Iterator[Frame]:
        for done, frame in enumerate(sequence.frames(step=frame_step), start=1):
            yield frame
            if on_progress is not None:
                on_progress(done, total)

    found = find_mugs(frames(), tracks)
    require_mugs(found, MIN_MUGS, str(path))
    summaries, views, windows = [], [], []
    for weight in weights:
        name = str(weight) if weight is not None else "shipped"
        # Torch, the reference runtime, as `ndfa ndf-eval` on rendered mugs: the model's figures.
        per_view = encode_views(found.views, NDFEncoder(weight, EncoderConfig(runtime="torch")), protocol)
        summary, per_window = measure(per_view, protocol)
        summaries.append(summary.with_columns(pl.lit(name).alias("weights")))
        views.append(per_view.with_columns(pl.lit(name).alias("weights")))
        windows.append(per_window.with_columns(pl.lit(name).alias("weights")))
    return RealMugResult(sequence, found, pl.concat(summaries), pl.concat(views), pl.concat(windows))


__all__ = ["MIN_MUGS", "ProtocolConfig", "RealMugResult", "TrackConfig", "evaluate_real_mugs"]
