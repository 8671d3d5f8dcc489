"""Plots of the evaluation results: `plot_sweep` draws a robustness sweep (`ndfa.eval.sweep`)
with Pillow (matplotlib is not a dependency)."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from ndfa.core.errors import SweepError
from ndfa.eval.sweep import METHODS
from ndfa.io.atomic import atomic_path

COLOURS = {"NN": (31, 119, 180), "PMT": (255, 127, 14), "ndfa": (44, 160, 44)}


def plot_sweep(table: pl.DataFrame, out_png: Path, title: str | None = None) -> Path:
    """Precision, recall and F1 against the axis value, one line per method: the mean over seeds
    with a min/max band. Drawn with Pillow (matplotlib is not a dependency)."""
    from PIL import Image, ImageDraw

    if table.is_empty():
        raise SweepError("nothing to plot: the sweep has no results")
    panel_w, panel_h, margin = 360, 300, 50
    metrics = ("precision", "recall", "f1")
    width, height = margin + len(metrics) * (panel_w + margin), panel_h + 2 * margin + 30
    image = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(image, "RGBA")
    axis = table["axis"][0]
    draw.text((margin, 10), title or f"sweep over {axis}: mean over seeds, band = min..max", fill="black")
    xs = sorted(table["x"].unique().to_list())
    labels = {row["x"]: row["value"] for row in table.select("x", "value").unique().iter_rows(named=True)}
    # The values sit evenly spaced (sweeps are often geometric: 0, 1, 2, 4, 8), labelled with their values.
    positions = {x: i for i, x in enumerate(xs)}
    p_lo, p_hi = 0, max(1, len(xs) - 1)
    stats = (table.group_by(["x", "method"]).agg(
        *[pl.col(m).mean().alias(f"{m}_mean") for m in metrics], *[pl.col(m).min().alias(f"{m}_min") for m in metrics],
        *[pl.col(m).max().alias(f"{m}_max") for m in metrics]).sort("x"))
    for k, metric in enumerate(metrics):
        left, top = margin + k * (panel_w + margin), margin + 20
        right, bottom = left + panel_w, top + panel_h

        def px(x: float) -> float:
            return left + (positions[x] - p_lo) / (p_hi - p_lo) * panel_w

        def py(v: float) -> float:
            return bottom - v * panel_h

        draw.rectangle([left, top, right, bottom], outline="black")
        for v in (0.0, 0.25, 0.5, 0.75, 1.0):
            draw.line([left, py(v), right, py(v)], fill=(220, 220, 220))
            draw.text((left - 30, py(v) - 6), f"{v:.2f}", fill="black")
        for x in xs:
            draw.text((px(x) - 12, bottom + 5), labels[x], fill="black")
        draw.text((left + panel_w // 2 - 20, top - 16), metric, fill="black")
        draw.text((left + panel_w // 2 - 20, bottom + 20), axis, fill="black")
        for method in METHODS:
            rows = stats.filter(pl.col("method") == method).sort("x")
            if rows.is_empty():
                continue
            colour = COLOURS.get(method, (0, 0, 0))
            upper = [(px(r["x"]), py(r[f"{metric}_max"])) for r in rows.iter_rows(named=True)]
            lower = [(px(r["x"]), py(r[f"{metric}_min"])) for r in rows.iter_rows(named=True)]
            if len(upper) > 1:
                draw.polygon(upper + lower[::-1], fill=(*colour, 50))
            line = [(px(r["x"]), py(r[f"{metric}_mean"])) for r in rows.iter_rows(named=True)]
            if len(line) > 1:
                draw.line(line, fill=colour, width=2)
            for x, y in line:
                draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)
    for i, method in enumerate(METHODS):
        x0 = width - margin - 80 * (len(METHODS) - i)
        draw.line([x0, 16, x0 + 20, 16], fill=COLOURS[method], width=3)
        draw.text((x0 + 24, 10), method, fill="black")
    out_png = Path(out_png)
    with atomic_path(out_png) as temporary:
        image.save(temporary, format="PNG")  # the temporary name has no .png suffix to tell Pillow
    return out_png
