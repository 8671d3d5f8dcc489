"""`ndfa ndf-eval --real DIR`: the real-mug protocol (`ndfa.eval.real_mugs`), its tables and summary."""

from __future__ import annotations

import math
from pathlib import Path

from rich.table import Table

from ndfa.cli.app import console, err_console, progress_bar

SUMMARY, VIEWS, WINDOWS = "real_summary.parquet", "real_views.parquet", "real_windows.parquet"

# The summary's figures as printed: (column, label, format).
FIGURES = [
    ("views", "views", "{:.0f}"),
    ("brightness", "brightness (0-255)", "{:.0f}"),
    ("azimuth_span_deg", "azimuth span, all views (deg)", "{:.0f}"),
    ("windows", "windows >= 45 deg", "{:.0f}"),
    ("window_views", "views in windows", "{:.0f}"),
    ("windowed_centroid_mm", "windowed: visible centroid spread (mm)", "{:.1f}"),
    ("windowed_center_mm", "windowed: NDF center spread (mm)", "{:.1f}"),
    ("windowed_ratio", "windowed: ratio center / centroid", "{:.2f}"),
    ("windowed_centroid_height_mm", "windowed: centroid height spread (mm)", "{:.1f}"),
    ("windowed_pose_free_centroid_mm", "windowed, pose-free: centroid - wall circle (mm)", "{:.1f}"),
    ("windowed_pose_free_center_mm", "windowed, pose-free: NDF center - wall circle (mm)", "{:.1f}"),
    ("windowed_pose_free_ratio", "windowed, pose-free: ratio", "{:.2f}"),
    ("windowed_center_height_mm", "windowed: center height spread (mm)", "{:.1f}"),
    ("all_views_centroid_mm", "all views: visible centroid spread (mm)", "{:.1f}"),
    ("all_views_center_mm", "all views: NDF center spread (mm)", "{:.1f}"),
    ("all_views_ratio", "all views: ratio center / centroid", "{:.2f}"),
    ("same_cosine_median", "same-mug code cosine, median", "{:.3f}"),
    ("cross_cosine_median", "cross-mug code cosine, median", "{:.3f}"),
    ("same_above_delta_s", "same-mug pairs above delta_s", "{:.2f}"),
    ("cross_above_delta_s", "cross-mug pairs above delta_s", "{:.2f}"),
    ("code_auc", "AUC same over cross", "{:.3f}"),
    ("mean_code_cosine", "cosine of the mugs' mean codes", "{:.3f}"),
]


def real_mugs_command(real: Path, weights: list[Path] | None, out: Path, frame_step: int) -> None:
    """Run the protocol on `real` for each of `weights` (default: the shipped ones), write its
    tables to `out` and print the figures."""
    from ndfa.eval.real_mugs import ProtocolConfig, evaluate_real_mugs
    from ndfa.io.atomic import write_parquet

    with progress_bar() as progress:
        task = progress.add_task("segmenting", total=None)
        result = evaluate_real_mugs(real, list(weights or [None]), frame_step=frame_step,
                                    on_progress=lambda done, total: progress.update(task, completed=done, total=total))
    out.mkdir(parents=True, exist_ok=True)
    write_parquet(result.views, out / VIEWS)
    write_parquet(result.windows, out / WINDOWS)
    write_parquet(result.summary, out / SUMMARY)

    found = result.tracks
    err_console.print(f"{real}: {found.frames} frames (every {frame_step}), up: {result.sequence.up}; "
                      f"{found.mugs} mugs of {len(found.track_sizes)} position tracks (a mug: >= {found.min_views} views)")
    config = ProtocolConfig()
    table = Table(title=f"ndfa ndf-eval --real: mug 0 is the brightest; windows: >= {config.min_angle_deg:g} deg of "
                        f"azimuth within {config.max_window_s:g} s, centroid moved >= {1e3 * config.min_centroid_move_m:g} mm")
    table.add_column("figure")
    rows = result.summary.to_dicts()
    for row in rows:
        weights_name = Path(row["weights"]).parent.name or row["weights"]
        table.add_column(f"{weights_name}\nmug {row['mug']}", justify="right")
    for column, label, form in FIGURES:
        table.add_row(label, *(_format(form, row[column]) for row in rows))
    console.print(table)
    for row in rows:
        if row["mug"] == "all":
            console.print(
                f"{row['weights']}: NDF center spread {_format('{:.1f}', row['windowed_center_mm'])} mm vs visible centroid "
                f"{_format('{:.1f}', row['windowed_centroid_mm'])} mm over {row['windows']} windows of views >= "
                f"{config.min_angle_deg:g} deg apart: ratio {_format('{:.2f}', row['windowed_ratio'])} (target <= 0.5; "
                f"all views {_format('{:.2f}', row['all_views_ratio'])}; pose-free, against each view's wall circle: "
                f"{_format('{:.2f}', row['windowed_pose_free_ratio'])}); codes: same-mug median "
                f"{_format('{:.2f}', row['same_cosine_median'])}, cross-mug {_format('{:.2f}', row['cross_cosine_median'])} "
                f"({_format('{:.0%}', row['cross_above_delta_s'])} above delta_s {config.delta_s:g}), AUC "
                f"{_format('{:.2f}', row['code_auc'])}", highlight=False)
    console.print(f"tables in {out}: {SUMMARY}, {VIEWS}, {WINDOWS}")


def _format(form: str, value: float | int | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return form.format(value)
